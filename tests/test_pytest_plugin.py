"""The depthview pytest plugin (service/pytest_plugin.py, service/image_check.py),
run on test files of its own with pytester: a passing check, a failing one that
writes its four files, a missing reference, --depthview-update-refs, and the
README's user test file on a small GLB (GL and Embree fixtures), which must pass,
fail with error images when the model changes, and take a new reference on request."""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import numpy as np
import pytest

from service.image_check import DEFAULTS, compare_images, read_image
from tests.helpers import ROOT, write_small_glb

FILES = re.compile(r"^E?\s*(actual|expected|error|bad pixels):\s+(\S+)", re.M)

CHECKS = '''
import numpy as np
from service.image_check import assert_images_close, assert_matches_reference

def image(level=120, spot=None):
    img = np.full((24, 32, 3), level, np.uint8)
    if spot is not None:
        img[4:8, 10:14] = spot
    return img

def test_close():
    near = image()
    near[::2, ::2] += 1  # a quarter of the pixels one level up: mean 0.25/255, none above 1/255
    assert_images_close(near, image())

def test_spot_srgb():
    assert_images_close(image(spot=250), image(), name="spot")

def test_spot_linear():
    a = image(spot=250).astype(np.float32) / 255
    assert_images_close(a, image().astype(np.float32) / 255, metric="psnr")

def test_reference():
    assert_matches_reference(image(spot=SPOT), "ref")
'''


def written_files(text: str) -> dict[str, Path]:
    return {kind: Path(p) for kind, p in FILES.findall(text)}


def checks_file(pytester: pytest.Pytester, spot: int | None) -> None:
    pytester.makepyfile(test_checks=CHECKS.replace("SPOT", repr(spot)))


def test_passing_and_failing_checks_write_four_files(pytester):
    checks_file(pytester, None)
    out = pytester.path / "out"
    result = pytester.runpytest("-k", "close or spot", f"--depthview-output={out}")
    result.assert_outcomes(passed=1, failed=2)
    text = result.stdout.str()
    assert "images differ (mae, srgb): MAE" in text and "images differ (psnr, linear): PSNR" in text
    folders = sorted(p.name for p in out.iterdir())
    assert folders == ["test_checks.py_test_spot_linear", "test_checks.py_test_spot_srgb"]  # none for the pass
    srgb = sorted(p.name for p in (out / folders[1]).iterdir())
    assert srgb == ["spot_actual.png", "spot_bad.png", "spot_error.png", "spot_expected.png"]
    linear = sorted(p.name for p in (out / folders[0]).iterdir())
    assert linear == ["image_actual.exr", "image_bad.png", "image_error.png", "image_expected.exr"]
    named = {Path(p) for _, p in FILES.findall(text)}  # the message names every file written
    assert named == {p for folder in folders for p in (out / folder).iterdir()}
    # the files hold what the check compared: the spot is the only bad region
    bad = read_image(out / folders[1] / "spot_bad.png")
    assert bad.shape == (24, 32) and set(np.unique(bad)) == {0, 255}
    assert np.array_equal(np.argwhere(bad == 255).min(0), [4, 10]) and np.array_equal(np.argwhere(bad).max(0), [7, 13])
    assert read_image(out / folders[1] / "spot_actual.png")[5, 11].tolist() == [250, 250, 250]
    np.testing.assert_allclose(read_image(out / folders[0] / "image_actual.exr")[5, 11], 250 / 255, rtol=1e-6)
    assert read_image(out / folders[1] / "spot_error.png").shape == (24, 32, 3)


def test_missing_reference_fails_and_says_how_to_create_it(pytester):
    checks_file(pytester, None)
    result = pytester.runpytest("-k", "reference")
    result.assert_outcomes(failed=1)
    ref = pytester.path / "refs" / "test_checks" / "ref.png"
    result.stdout.fnmatch_lines([f"*reference image {ref} does not exist*", "*--depthview-update-refs*"])
    assert not ref.exists()


def test_update_refs_creates_then_rewrites_only_on_request(pytester):
    checks_file(pytester, None)
    ref = pytester.path / "refs" / "test_checks" / "ref.png"
    result = pytester.runpytest("-k", "reference", "--depthview-update-refs")
    result.assert_outcomes(passed=1)
    result.stdout.fnmatch_lines(["*depthview: reference images written*", str(ref), "1 reference image(s) written*"])
    assert read_image(ref).shape == (24, 32, 3)
    pytester.runpytest("-k", "reference").assert_outcomes(passed=1)
    before = ref.read_bytes()
    checks_file(pytester, 250)  # the "model" changed
    result = pytester.runpytest("-k", "reference")
    result.assert_outcomes(failed=1)
    assert set(written_files(result.stdout.str())) == {"actual", "expected", "error", "bad pixels"}
    assert ref.read_bytes() == before and "rewrite it with `pytest --depthview-update-refs`" in result.stdout.str()
    result = pytester.runpytest("-k", "reference", "--depthview-update-refs")
    result.assert_outcomes(passed=1)
    assert ref.read_bytes() != before and read_image(ref)[5, 11].tolist() == [250, 250, 250]
    pytester.runpytest("-k", "reference").assert_outcomes(passed=1)


def test_each_reference_belongs_to_one_check(pytester):
    """Two unnamed checks of one test, or two test ids that make one file name, would share
    (and overwrite) one reference: each is an error naming the file and what to do."""
    pytester.makepyfile(test_twice='''
import numpy as np
import pytest
from service.image_check import assert_matches_reference

def test_two_unnamed():
    assert_matches_reference(np.zeros((4, 4, 3), np.uint8))
    assert_matches_reference(np.zeros((4, 4), np.float32))

@pytest.mark.parametrize("room", ["room a", "room/a"])
def test_rooms(room):
    assert_matches_reference(np.zeros((4, 4, 3), np.uint8))

def test_named():
    assert_matches_reference(np.zeros((4, 4, 3), np.uint8), "colour")
    assert_matches_reference(np.zeros((4, 4), np.float32), "depth")

def test_shares_a_named_reference():  # a name given on purpose may be shared
    assert_matches_reference(np.zeros((4, 4, 3), np.uint8), "colour")
''')
    result = pytester.runpytest("--depthview-update-refs")
    result.assert_outcomes(passed=3, failed=2)
    text = result.stdout.str()
    assert "test_two_unnamed.exr is checked twice by test_twice.py::test_two_unnamed" in text.replace("\n", "")
    assert "is already the reference of test_twice.py::test_rooms[room a]; test_twice.py::test_rooms[room/a] " \
           "makes the same file name" in text.replace("\n", "")
    written = [ln for ln in text.splitlines() if ln.endswith((".png", ".exr")) and "refs" in ln]
    assert len(written) == len(set(written)) == 4  # two_unnamed's first, room a, colour, depth


def test_an_output_folder_shows_this_runs_failures_only(pytester):
    """A test that failed (its four files written) and then passes leaves no files of the
    earlier failure in --depthview-output; files of other names stay."""
    checks_file(pytester, None)
    out = pytester.path / "out"
    pytester.runpytest("-k", "spot_srgb", f"--depthview-output={out}").assert_outcomes(failed=1)
    folder = out / "test_checks.py_test_spot_srgb"
    assert len(list(folder.iterdir())) == 4
    (folder / "notes.txt").write_text("mine")
    pytester.makepyfile(test_checks=CHECKS.replace("SPOT", "None").replace("image(spot=250), image()",
                                                                        "image(), image()"))
    pytester.runpytest("-k", "spot_srgb", f"--depthview-output={out}").assert_outcomes(passed=1)
    assert [p.name for p in folder.iterdir()] == ["notes.txt"]


def test_ids_sharing_an_output_folder_keep_each_others_files(pytester):
    """'room a' and 'room/a' make one folder: the second test does not clear the first's files."""
    pytester.makepyfile(test_rooms='''
import numpy as np
import pytest
from service.image_check import assert_images_close

@pytest.mark.parametrize("room", ["room a", "room/a"])
def test_rooms(room):
    assert_images_close(np.ones((4, 4), np.float32), np.zeros((4, 4), np.float32))
''')
    out = pytester.path / "out"
    pytester.runpytest(f"--depthview-output={out}").assert_outcomes(failed=2)
    names = sorted(p.name for p in (out / "test_rooms.py_test_rooms_room_a").iterdir())
    assert "image_actual.exr" in names and "image_2_actual.exr" in names


def readme_user_test() -> str:
    """The README's complete user test file (the first python block of its plugin section)."""
    text = (ROOT / "README.md").read_text()
    section = text[text.index("## Image checks in your own pytest suite"):]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def test_readme_user_file_on_a_glb_passes_fails_on_change_and_updates(pytester):
    """The README's test file as a user would run it: GL and Embree fixtures on a
    small GLB; a changed model fails the reference check with error images, the GL
    vs Embree check still passes; --depthview-update-refs takes the new frame."""
    pytester.makepyfile(test_my_model=readme_user_test())
    write_small_glb(pytester.path / "model.glb")
    ref = pytester.path / "refs" / "test_my_model" / "front.exr"
    result = pytester.runpytest()
    result.assert_outcomes(passed=1, failed=1)
    result.stdout.fnmatch_lines(["*reference image*front.exr does not exist*"])
    pytester.runpytest("--depthview-update-refs").assert_outcomes(passed=2)
    assert ref.exists()
    pytester.runpytest().assert_outcomes(passed=2)
    write_small_glb(pytester.path / "model.glb", ball_radius=0.6)  # the model changed
    result = pytester.runpytest()
    result.assert_outcomes(passed=1, failed=1)
    files = written_files(result.stdout.str())
    assert set(files) == {"actual", "expected", "error", "bad pixels"} and all(p.exists() for p in files.values())
    bad = read_image(files["bad pixels"]) == 255
    assert 0.01 < bad.mean() < 0.5  # the ball's grown rim, not the whole frame
    pytester.runpytest("--depthview-update-refs").assert_outcomes(passed=2)
    pytester.runpytest().assert_outcomes(passed=2)


def test_plugin_adds_nothing_to_a_run_that_does_not_use_it(pytester):
    """Loaded by its entry point (options and fixtures listed) yet, in a run that
    does not use it, nothing heavy is imported and no file is written."""
    pytester.makepyfile(test_plain='''
import sys

def test_plain():
    assert "service.pytest_plugin" in sys.modules
    heavy = [m for m in ("numpy", "moderngl", "embreex", "service.image_check") if m in sys.modules]
    assert heavy == []
''')
    result = pytester.runpytest_subprocess("-p", "no:cacheprovider", "--basetemp", str(pytester.path / "tmp"))
    result.assert_outcomes(passed=1)
    assert not (pytester.path / "tmp" / "depthview").exists()
    assert "depthview:" not in result.stdout.str()  # (pytest's header lists the plugin: depthview-0.1.0)
    listing = pytester.runpytest_subprocess("--fixtures", "-p", "no:cacheprovider").stdout.str()
    for name in ("depthview_gl", "depthview_render", "depthview_reference"):
        assert name in listing


# --- the comparisons themselves (no pytest run inside) -------------------------------------

def test_mae_bounds_the_mean_and_each_pixel():
    a = np.zeros((20, 20, 3))
    b = a.copy()
    b[0, :5, 1] = 0.3  # five pixels (1.25 %), one channel each: MAE 1.5/1200
    c = compare_images(b, a, metric="mae")
    assert c.score == pytest.approx(1.5 / 1200) and c.bad_fraction == pytest.approx(0.0125)
    assert (c.tolerance, c.threshold, c.max_bad_fraction) == DEFAULTS["mae"]
    assert c.score_ok and not c.ok  # the mean is within 0.5/255, the 1.25 % bad pixels are over 1 %
    assert compare_images(b, a, metric="mae", max_bad_fraction=0.0125).ok
    assert compare_images(b, a, threshold=0.3).ok  # |a − b| = 0.3 is not above 0.3
    assert not compare_images(b, a, tolerance=0.01, max_bad_fraction=0.0124).ok  # one bad pixel too many
    flat = np.full((10, 10, 3), 1 / 255)  # every pixel off by one level: mean over 0.5/255, no pixel over 1/255
    c = compare_images(flat, a[:10, :10])
    assert c.bad_fraction == 0.0 and not c.score_ok
    assert compare_images(flat, a[:10, :10], tolerance=1.01 / 255).ok


def test_a_tolerance_without_a_threshold_sets_both():
    a = np.zeros((4, 4, 3))
    assert compare_images(a, a, metric="mae", tolerance=0.02).threshold == 0.02
    assert compare_images(a, a, metric="flip", tolerance=0.02).threshold == 0.02
    assert compare_images(a, a, metric="psnr", tolerance=30.0).threshold == pytest.approx(10 ** -1.5)
    c = compare_images(a, a, metric="mae", tolerance=0.02, threshold=0.5)
    assert (c.tolerance, c.threshold) == (0.02, 0.5)
    for metric, d in DEFAULTS.items():  # nothing given: the defaults, threshold included
        c = compare_images(a, a, metric=metric)
        assert (c.tolerance, c.threshold, c.max_bad_fraction) == d


def test_defaults_are_the_benchmarks_selection():
    """DEFAULTS are what bench/image_check_defaults.py selected (the module docstring and
    README cite its report)."""
    data = json.loads((ROOT / "bench" / "results" / "image_check_defaults.json").read_text())
    for metric, d in DEFAULTS.items():
        sel = data["selected"][metric]
        assert (sel["tolerance"], sel["threshold"], sel["max_bad"]) == pytest.approx(tuple(d), rel=1e-12), metric


def test_psnr_hand_value_and_its_pixel_threshold():
    a = np.zeros((4, 4))
    c = compare_images(a + 0.1, a, metric="psnr", tolerance=20.0)  # 10·log10(1 / 0.01) = 20 dB
    assert c.score == pytest.approx(20.0) and c.threshold == pytest.approx(0.1)
    assert c.score_ok and c.bad_fraction == 0.0  # |a − b| = 0.1 is not above 0.1
    assert compare_images(a, a, metric="psnr").score == float("inf")
    assert not compare_images(a + 0.1, a, metric="psnr").ok  # the default 35 dB
    assert compare_images(a + 0.015, a, metric="psnr").score == pytest.approx(36.478, abs=1e-3)
    c = compare_images(a + 0.015, a, metric="psnr")  # within 35 dB, but every pixel above 0.01
    assert c.score_ok and c.bad_fraction == 1.0 and not c.ok


def test_flip_sees_a_change_and_not_its_absence():
    a = np.full((32, 32, 3), 0.4)
    assert compare_images(a, a, metric="flip").score == 0.0
    b = a.copy()
    b[8:16, 8:16] = 1.0
    c = compare_images(b, a, metric="flip")
    assert not c.ok and c.bad[8:16, 8:16].all()
    outside = np.ones_like(c.bad)
    outside[4:20, 4:20] = False
    assert not c.bad[outside].any()  # FLIP's filters spread the change by a few pixels only


def test_non_finite_values_spaces_masks_and_shapes():
    depth = np.full((4, 4), np.inf, np.float32)
    depth[1:3, 1:3] = 2.0
    assert compare_images(depth, depth.copy()).score == 0.0  # +inf background = +inf background
    other = depth.copy()
    other[0, 0] = 5.0
    c = compare_images(other, depth, max_bad_fraction=1.0)
    assert c.score == float("inf") and c.bad[0, 0] and c.bad.sum() == 1 and not c.ok
    mask = np.zeros((4, 4), bool)
    mask[1:3, 1:3] = True
    assert compare_images(other, depth, mask=mask).ok  # only the masked pixels count
    with pytest.raises(ValueError, match="selects no pixel"):
        compare_images(depth, depth, mask=np.zeros((4, 4), bool))
    with pytest.raises(ValueError, match="integer"):
        compare_images(np.zeros((2, 2, 3), np.uint8), np.zeros((2, 2, 3)))
    assert compare_images(np.full((2, 2, 3), 255, np.uint8), np.ones((2, 2, 3)), space="srgb").score == 0.0
    with pytest.raises(ValueError, match="metric"):
        compare_images(depth, depth, metric="ssim")
    with pytest.raises(AssertionError, match="differ in shape"):
        from service.image_check import assert_images_close

        assert_images_close(np.zeros((4, 4)), np.zeros((4, 5)))


def test_outside_pytest_the_files_go_to_a_temporary_folder(tmp_path):
    code = ("import numpy as np\nfrom service.image_check import assert_images_close\n"
            "try:\n    assert_images_close(np.zeros((4, 4, 3), np.uint8), np.full((4, 4, 3), 9, np.uint8))\n"
            "except AssertionError as e:\n    print(e)\n")
    import subprocess

    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, timeout=60)
    files = written_files(out.stdout)
    assert set(files) == {"actual", "expected", "error", "bad pixels"} and all(p.exists() for p in files.values())


def test_fixture_arguments_are_checked_before_anything_renders(tmp_path):
    """The fixtures' scene and effects arguments: an unknown effect method or a
    missing model file is a clear error, not a frame without the effect."""
    from scenes import Camera
    from service.testing import reference_frame

    cam = Camera((2.0, 1.5, 2.5), (0.0, 0.0, 0.0), width=8, height=8)
    with pytest.raises(ValueError, match="reflections method 'ssr' is not available"):
        reference_frame("cornell", cam, {"reflections": "ssr"})
    with pytest.raises(FileNotFoundError, match="not a built-in scene"):
        reference_frame(tmp_path / "absent.glb", cam)
    frame = reference_frame(write_small_glb(tmp_path / "model.glb"), cam)
    assert frame.color.shape == (8, 8, 3) and frame.mask.any()

"""Image assertions for pytest suites (the depthview pytest plugin, service.pytest_plugin).

`assert_images_close(actual, expected, metric=...)` compares two images; on failure
it writes four files — actual, expected, a scaled error image and the bad-pixel
mask — to the output folder (pytest option `--depthview-output`, default
`<pytest basetemp>/depthview/<test>/`) and names them in the assertion message.
`assert_matches_reference(actual, name)` compares with a reference image kept
beside the test (`<test dir>/refs/<test module>/<name>.png|.exr`), which only
`pytest --depthview-update-refs` creates or rewrites.

Images are numpy arrays (H,W) or (H,W,C), row 0 = top. Colour space ("space"):
"srgb" — 8-bit (uint8; uint16 is /65535) or float in [0, 1], stored as PNG;
"linear" — float (any range, e.g. the renderer's linear colour or a depth map with
+inf background), stored as EXR; "auto" (default): integer arrays are sRGB, float
arrays linear. Errors are in [0, 1] units of the image values (x/255 = x levels
of an 8-bit image). Equal values (also +inf = +inf, NaN = NaN) differ by 0; any
other non-finite value is an infinite error.

Metrics — each bounds the whole image and each pixel; a check passes when the
image score is within `tolerance` and at most `max_bad_fraction` of the (masked)
pixels exceed the per-pixel `threshold` ("bad" pixels):

=========  ============================  ==========================  =========  =========  =======
metric     image score                   bad pixel                   tolerance  threshold  max bad
=========  ============================  ==========================  =========  =========  =======
``mae``    mean |a − b| over pixels and  some channel's |a − b| >    0.5/255    1/255      1 %
           channels ≤ tolerance          threshold
``psnr``   10·log10(1 / MSE) dB ≥        some channel's |a − b| >    35 dB      0.01       1 %
           tolerance                     threshold
``flip``   mean LDR-FLIP ≤ tolerance     FLIP > threshold            0.01       0.3        0.5 %
=========  ============================  ==========================  =========  =========  =======

A caller that gives a tolerance and no threshold gets the threshold that tolerance
implies (`pixel_threshold`: mae and flip the tolerance, psnr 10^(−tolerance/20)).
The defaults (`DEFAULTS`) are the ones bench/image_check_defaults.py selects: the GL
frame against Embree's truth of it passes on every frame it measures, with a
margin, and the most of its changed frames fail (its report:
bench/results/image_check_defaults.md).

FLIP (`flip-evaluator`, NVIDIA's perceptual difference at 67 pixels
per degree) compares (H,W) or (H,W,3) images with values in [0, 1] (clipped).
"""

from __future__ import annotations

import re
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np

METRICS = ("mae", "psnr", "flip")


class CheckBounds(NamedTuple):
    """A check's bounds: the image score's tolerance, the per-pixel threshold above
    which a pixel is bad, and the share of bad pixels allowed."""

    tolerance: float
    threshold: float
    max_bad_fraction: float


#: metric → the bounds used where the caller gives none (module docstring; calibrated
#: by bench/image_check_defaults.py, whose json records the selection).
DEFAULTS: dict[str, CheckBounds] = {"mae": CheckBounds(0.5 / 255, 1 / 255, 0.01),
                                    "psnr": CheckBounds(35.0, 0.01, 0.01),
                                    "flip": CheckBounds(0.01, 0.3, 0.005)}
SPACES = ("auto", "srgb", "linear")
#: The error image maps per-pixel error / (ERROR_SCALE × threshold) to magma's [0, 1].
ERROR_SCALE = 2.0


@dataclass
class Comparison:
    """The outcome of one comparison. score: the image metric (MAE, PSNR in dB,
    mean FLIP); pixel_error (H,W) float64: the per-pixel error the bad pixels are
    judged on (max channel |a − b|, or FLIP); threshold: the per-pixel bound;
    bad (H,W) bool: bad pixels inside the mask; pixels: pixels compared."""

    metric: str
    space: str
    score: float
    tolerance: float
    threshold: float
    max_bad_fraction: float
    pixel_error: np.ndarray
    bad: np.ndarray
    mask: np.ndarray
    pixels: int

    @property
    def bad_fraction(self) -> float:
        return float(self.bad.sum()) / self.pixels

    @property
    def score_ok(self) -> bool:
        return score_within(self.metric, self.score, self.tolerance)

    @property
    def ok(self) -> bool:
        return self.score_ok and self.bad_fraction <= self.max_bad_fraction

    def summary(self) -> str:
        """One line: the score against the tolerance and the bad pixels against their bound."""
        op = ("≥" if self.score_ok else "<") if self.metric == "psnr" else ("≤" if self.score_ok else ">")
        label = {"mae": "MAE", "psnr": "PSNR", "flip": "mean FLIP"}[self.metric]
        unit = " dB" if self.metric == "psnr" else ""
        return (f"{label} {self.score:.5g}{unit} {op} tolerance {self.tolerance:.5g}{unit}; "
                f"{100 * self.bad_fraction:.3g} % of {self.pixels} pixels bad (error > {self.threshold:.5g}), "
                f"allowed {100 * self.max_bad_fraction:.3g} %")


def score_within(metric: str, score: float, tolerance: float) -> bool:
    """The image score within the tolerance: PSNR at least it, MAE and mean FLIP at most."""
    return score >= tolerance if metric == "psnr" else score <= tolerance


def pixel_threshold(metric: str, tolerance: float) -> float:
    """The per-pixel threshold a tolerance implies when no threshold is given: mae
    and flip the tolerance itself, psnr the error 10^(−tolerance/20)."""
    return 10.0 ** (-tolerance / 20.0) if metric == "psnr" else tolerance


def compare_images(actual: np.ndarray, expected: np.ndarray, *, metric: str = "mae", tolerance: float | None = None,
                   threshold: float | None = None, max_bad_fraction: float | None = None,
                   mask: np.ndarray | None = None, space: str = "auto") -> Comparison:
    """Compare two images (module docstring); raises ValueError on unusable input
    (unknown metric or space, shapes that differ, an empty mask). Bounds not given
    are the metric's DEFAULTS, except that a given tolerance without a threshold
    also sets the threshold (pixel_threshold)."""
    if metric not in METRICS:
        raise ValueError(f"metric must be one of {METRICS}, got {metric!r}")
    default = DEFAULTS[metric]
    tol = float(default.tolerance if tolerance is None else tolerance)
    if threshold is not None:
        thr = float(threshold)
    else:
        thr = default.threshold if tolerance is None else pixel_threshold(metric, tol)
    max_bad = float(default.max_bad_fraction if max_bad_fraction is None else max_bad_fraction)
    space = resolve_space(actual, expected, space)
    a, b = as_unit(actual, space), as_unit(expected, space)
    if a.shape != b.shape:
        raise ValueError(f"image shapes differ: actual {np.shape(actual)}, expected {np.shape(expected)}")
    sel = np.ones(a.shape[:2], bool) if mask is None else np.asarray(mask, bool)
    if sel.shape != a.shape[:2]:
        raise ValueError(f"mask shape {sel.shape} does not match the images' {a.shape[:2]}")
    if not sel.any():
        raise ValueError("the mask selects no pixel: the check would pass whatever the images hold")
    diff = abs_diff(a, b)
    pixel = diff.max(axis=2)
    if metric == "mae":
        score = float(diff[sel].mean())
    elif metric == "psnr":
        mse = float(np.mean(diff[sel] ** 2))
        score = float("inf") if mse == 0 else (0.0 if np.isinf(mse) else 10.0 * np.log10(1.0 / mse))
    else:
        from reference.image_metrics import flip_map

        flip = flip_map(a, b, srgb=space == "srgb").astype(np.float64)
        pixel = np.where(np.isinf(pixel), np.inf, flip)  # a non-finite mismatch is a bad pixel whatever FLIP says
        score = float(pixel[sel].mean())
    return Comparison(metric, space, score, tol, thr, max_bad, pixel, (pixel > thr) & sel, sel,
                      int(sel.sum()))


def resolve_space(actual: np.ndarray, expected: np.ndarray, space: str) -> str:
    """'srgb' or 'linear' for the pair (module docstring); mixed 8-bit and float
    input under "auto" is an error (convert one, or say which space both are in)."""
    if space not in SPACES:
        raise ValueError(f"space must be one of {SPACES}, got {space!r}")
    ints = [np.issubdtype(np.asarray(x).dtype, np.integer) for x in (actual, expected)]
    if space == "linear" and any(ints):
        raise ValueError("integer images are sRGB levels; pass space='srgb' (or compare float images)")
    if space != "auto":
        return space
    if ints[0] != ints[1]:
        raise ValueError("one image is integer (sRGB levels) and the other float: convert one, or pass "
                         "space='srgb' (float values sRGB-encoded in [0, 1])")
    return "srgb" if ints[0] else "linear"


def as_unit(img: np.ndarray, space: str) -> np.ndarray:
    """(H,W,C) float64 in [0, 1] units: integer levels divided by their maximum."""
    x = np.asarray(img)
    if x.dtype == bool:
        raise ValueError("boolean arrays are masks, not images")
    if x.ndim not in (2, 3):
        raise ValueError(f"images are (H,W) or (H,W,C) arrays, got shape {x.shape}")
    scale = float(np.iinfo(x.dtype).max) if np.issubdtype(x.dtype, np.integer) else 1.0
    x = x.astype(np.float64) / scale
    return x[..., None] if x.ndim == 2 else x


def _shape3(img: np.ndarray) -> tuple[int, ...]:
    """Shape with the channel axis: (H,W) → (H,W,1)."""
    shape = np.shape(img)
    return shape if len(shape) != 2 else (*shape, 1)


def abs_diff(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """|a − b|, 0 where the values are equal (also +inf/+inf, NaN/NaN), +inf where
    they differ and one is not finite."""
    with np.errstate(invalid="ignore"):
        d = np.abs(a - b)
    same = (a == b) | (np.isnan(a) & np.isnan(b))
    return np.where(same, 0.0, np.where(np.isfinite(d), d, np.inf))


# --- files ---------------------------------------------------------------------------

def write_image(path_stem: Path, img: np.ndarray, space: str) -> Path:
    """Write `img` as `path_stem`.png (sRGB: 8-bit levels) or .exr (linear: float32,
    channels Y, RGB or RGB + A, else C0, C1, ...); returns the path written."""
    x = np.asarray(img)
    path_stem.parent.mkdir(parents=True, exist_ok=True)
    if space == "srgb":
        levels = x if x.dtype == np.uint8 else np.rint(np.clip(as_unit(x, space), 0, 1) * 255).astype(np.uint8)
        return _write_png(path_stem.with_suffix(".png"), levels)
    from service.image_io import encode_exr

    f = np.asarray(x, np.float32)
    chans = f[..., None] if f.ndim == 2 else f
    n = chans.shape[2]
    if n == 1:
        named = {"Y": chans[..., 0]}
    elif n in (3, 4):
        named = {"RGB": chans[..., :3], **({"A": chans[..., 3]} if n == 4 else {})}
    else:
        named = {f"C{k}": chans[..., k] for k in range(n)}
    path = path_stem.with_suffix(".exr")
    path.write_bytes(encode_exr(named))
    return path


def read_image(path: Path) -> np.ndarray:
    """A PNG (uint8 levels, (H,W) grey or (H,W,C)) or an EXR written by write_image (float32)."""
    if path.suffix == ".png":
        from PIL import Image

        with Image.open(path) as im:
            return np.asarray(im)
    from service.image_io import decode_exr

    ch = decode_exr(path.read_bytes())
    if "Y" in ch:
        return ch["Y"]
    if "RGB" in ch:
        return np.dstack([ch["RGB"], ch["A"]]) if "A" in ch else ch["RGB"]
    return np.dstack([ch[f"C{k}"] for k in range(len(ch))])


def _write_png(path: Path, levels: np.ndarray) -> Path:
    from PIL import Image

    arr = np.ascontiguousarray(levels[..., 0] if levels.ndim == 3 and levels.shape[2] == 1 else levels)
    Image.fromarray(arr).save(path)
    return path


def error_picture(cmp: Comparison) -> np.ndarray:
    """(H,W,3) uint8: per-pixel error / (ERROR_SCALE × threshold) through magma
    (black = 0, the threshold mid-scale, light yellow ≥ ERROR_SCALE × threshold);
    pixels outside the mask dark grey."""
    import matplotlib

    v = np.clip(np.nan_to_num(cmp.pixel_error / (ERROR_SCALE * cmp.threshold), nan=1.0, posinf=1.0), 0.0, 1.0)
    rgb = (matplotlib.colormaps["magma"](v)[..., :3] * 255).round().astype(np.uint8)
    rgb[~cmp.mask] = 48
    return rgb


def mask_picture(cmp: Comparison) -> np.ndarray:
    """(H,W) uint8: bad pixels white, good ones black, outside the mask grey."""
    out = np.where(cmp.bad, 255, 0).astype(np.uint8)
    out[~cmp.mask] = 96
    return out


# --- the assertions --------------------------------------------------------------------

def assert_images_close(actual: np.ndarray, expected: np.ndarray, *, metric: str = "mae",
                        tolerance: float | None = None, threshold: float | None = None,
                        max_bad_fraction: float | None = None, mask: np.ndarray | None = None,
                        space: str = "auto", name: str | None = None) -> Comparison:
    """Assert that `actual` is close to `expected` (module docstring: metrics,
    defaults, colour spaces); returns the Comparison. On failure, writes
    <name>_actual, <name>_expected (PNG for sRGB, EXR for linear float data),
    <name>_error.png and <name>_bad.png to the test's output folder and raises
    AssertionError naming them. Images whose shapes differ fail the same way
    (actual and expected only); unusable arguments raise ValueError."""
    __tracebackhide__ = True  # pytest shows the caller's line, not ours
    space = resolve_space(actual, expected, space)
    if _shape3(actual) != _shape3(expected):
        out = _artifacts(name)
        files = [write_image(out.stem("actual"), actual, space), write_image(out.stem("expected"), expected, space)]
        raise AssertionError(f"images differ in shape: actual {np.shape(actual)}, expected {np.shape(expected)}\n"
                             + _listing(files))
    cmp = compare_images(actual, expected, metric=metric, tolerance=tolerance, threshold=threshold,
                         max_bad_fraction=max_bad_fraction, mask=mask, space=space)
    if cmp.ok:
        return cmp
    out = _artifacts(name)
    files = [write_image(out.stem("actual"), actual, space), write_image(out.stem("expected"), expected, space),
             _write_png(out.stem("error").with_suffix(".png"), error_picture(cmp)),
             _write_png(out.stem("bad").with_suffix(".png"), mask_picture(cmp))]
    notes = ["", "", f"per-pixel error / ({ERROR_SCALE:g} × {cmp.threshold:.5g}), magma; grey: outside the mask",
             "white: bad pixel; grey: outside the mask"]
    raise AssertionError(f"images differ ({metric}, {cmp.space}): {cmp.summary()}\n" + _listing(files, notes))


def assert_matches_reference(actual: np.ndarray, name: str | None = None, *, metric: str = "mae",
                             tolerance: float | None = None, threshold: float | None = None,
                             max_bad_fraction: float | None = None,
                             mask: np.ndarray | None = None, space: str = "auto",
                             ref_dir: str | Path | None = None) -> Path:
    """Assert that `actual` is close to the stored reference image `name` (default:
    the test's name) and return the reference's path. References live beside the
    test, in `<test dir>/refs/<test module>/` (or `ref_dir`), as PNG (sRGB) or EXR
    (linear float). A missing reference fails, saying how to create it; with
    `pytest --depthview-update-refs` a missing or differing reference is written
    from `actual` instead (and listed at the end of the run). The comparison is
    `assert_images_close` (its files are written on failure)."""
    __tracebackhide__ = True
    from service import pytest_plugin

    run = pytest_plugin.current_run()
    space = resolve_space(actual, actual, space)
    folder, stem = _reference_place(run, name, ref_dir)
    path = (folder / stem).with_suffix(".png" if space == "srgb" else ".exr")
    if run is not None and name is None:
        run.claim(path)
    update = run is not None and run.update_refs
    if not path.exists():
        if update:
            return run.wrote(write_image(path.with_suffix(""), actual, space))
        other = [p.name for p in folder.glob(f"{stem}.*") if p.suffix in (".png", ".exr")]
        hint = f" ({', '.join(other)} exists: a {'linear' if space == 'srgb' else 'sRGB'} image?)" if other else ""
        seen = write_image(_artifacts(stem).stem("actual"), actual, space)
        raise AssertionError(f"reference image {path} does not exist{hint}; this run's image is {seen}.\n"
                             "Create it with `pytest --depthview-update-refs` (then look at it and commit it).")
    expected = read_image(path)
    if update:
        cmp = compare_images(actual, expected, metric=metric, tolerance=tolerance, threshold=threshold,
                             max_bad_fraction=max_bad_fraction, mask=mask, space=space) \
            if _shape3(actual) == _shape3(expected) else None
        if cmp is None or not cmp.ok:
            run.wrote(write_image(path.with_suffix(""), actual, space))
        return path
    try:
        assert_images_close(actual, expected, metric=metric, tolerance=tolerance, threshold=threshold,
                            max_bad_fraction=max_bad_fraction, mask=mask, space=space, name=stem)
    except AssertionError as exc:
        raise AssertionError(f"{exc}\nreference: {path} (rewrite it with `pytest --depthview-update-refs` if the "
                             "change is intended)") from None
    return path


# --- where files go -----------------------------------------------------------------------

def safe_name(text: str) -> str:
    """A file-name-safe version of a test id or check name."""
    return re.sub(r"[^\w.-]+", "_", text).strip("_")[:120] or "image"


@dataclass
class _Artifacts:
    folder: Path
    name: str

    def stem(self, kind: str) -> Path:
        return self.folder / f"{self.name}_{kind}"


_FALLBACK_DIR: list[Path] = []


def _artifacts(name: str | None) -> _Artifacts:
    """Where a failing check writes its files: the plugin's output folder for the
    current test (a fresh temporary folder outside pytest); unnamed checks are
    image, image_2, ... in call order."""
    from service import pytest_plugin

    run = pytest_plugin.current_run()
    if run is None:
        if not _FALLBACK_DIR:
            _FALLBACK_DIR.append(Path(tempfile.mkdtemp(prefix="depthview-")))
        return _Artifacts(_FALLBACK_DIR[0], safe_name(name or "image"))
    folder, base = run.test_output_dir(), safe_name(name or "image")
    return _Artifacts(folder, run.unique_name(folder, base))


def _reference_place(run: object, name: str | None, ref_dir: str | Path | None) -> tuple[Path, str]:
    item = getattr(run, "item", None)
    if ref_dir is None and item is None:
        raise ValueError("outside a pytest test, pass ref_dir= (where the reference images live)")
    if name is None and item is None:
        raise ValueError("outside a pytest test, name the reference image")
    folder = Path(ref_dir) if ref_dir is not None else Path(item.path).parent / "refs" / Path(item.path).stem
    return folder, safe_name(name if name is not None else item.name)


def _listing(files: list[Path], notes: list[str] | None = None) -> str:
    labels = ("actual", "expected", "error", "bad pixels")
    lines = []
    for k, f in enumerate(files):
        note = (notes or [""] * len(files))[k]
        lines.append(f"  {labels[k] + ':':<12}{f}" + (f"  ({note})" if note else ""))
    return "\n".join(lines)

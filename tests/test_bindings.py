"""Unit tables (gl_passes.bindings): image units fit GL 4.3's guaranteed 8, and no
shader binds two of its images to one unit (NVIDIA's driver refuses `binding = 8`
on an image; llvmpipe accepts it, so the CPU suite checks the tables instead)."""

from __future__ import annotations

import re

import pytest

from gl_passes.bindings import MAX_IMAGE_UNITS, Units
from gl_passes.cluster_units import UNITS
from gl_passes.keyframe import REUSE_UNITS
from gl_passes.quad_splats import SPLAT_UNITS
from gl_passes.reconstruction import _UNITS as RECONSTRUCTION_UNITS
from gl_passes.shaders import SHADER_DIR, shader_source
from gl_passes.shadows import LOOKUP_UNITS

TABLES = (UNITS, REUSE_UNITS, RECONSTRUCTION_UNITS, LOOKUP_UNITS, SPLAT_UNITS)
_IMAGE = re.compile(r"layout\s*\([^)]*binding\s*=\s*UNIT_(\w+)[^)]*\)"  # an image declaration's unit
                    r"[^;]*\buniform\b[^;]*\b[iu]?image[0-9A-Z]\w*\s+\w+\s*;")


def test_flat_images_count_from_zero_and_groups_restart() -> None:
    flat = Units(images=("a", "b", "c"), storage=("s",), textures=("t", "u"))
    assert flat.image_units == {"a": 0, "b": 1, "c": 2}
    assert flat.defines() == {"UNIT_a": "0", "UNIT_b": "1", "UNIT_c": "2", "UNIT_s": "0", "UNIT_t": "0",
                              "UNIT_u": "1"}
    grouped = Units(images=(("a", "b"), ("c",), ("d", "e", "f")))
    assert grouped.image_units == {"a": 0, "b": 1, "c": 0, "d": 0, "e": 1, "f": 2}


@pytest.mark.parametrize("images, message", [
    ((tuple(f"i{k}" for k in range(MAX_IMAGE_UNITS + 1)),), "at most 8"),
    (("a", ("b",)), "groups are tuples"),
    ((("a", "b"), ("b",)), "'b' listed twice"),
])
def test_bad_image_tables_are_refused(images: tuple, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        Units(images=images)


def test_every_shader_binds_its_images_to_distinct_units_below_the_limit() -> None:
    units: dict[str, int] = {}
    for table in TABLES:
        for name, unit in table.image_units.items():
            assert units.setdefault(name, unit) == unit  # one name, one unit in every table
    checked = 0
    for path in sorted(SHADER_DIR.iterdir()):
        if path.suffix == ".glsl":
            continue
        names = list(dict.fromkeys(_IMAGE.findall(shader_source(path.name))))  # #ifdef variants declare twice
        bound = {n: units[n] for n in names}
        assert max(bound.values(), default=0) < MAX_IMAGE_UNITS, (path.name, bound)
        assert len(set(bound.values())) == len(bound), f"{path.name} binds two images to one unit: {bound}"
        checked += bool(names)
    assert checked >= 10  # the image-writing compute shaders were found

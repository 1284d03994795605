"""The depthview pytest plugin (entry point `pytest11: depthview`), loaded by pytest
wherever depthview is installed.

It adds two options and three fixtures, and nothing else to a run that does not
use them: this module imports only pytest and the standard library; GL, Embree
and numpy load when a fixture or an image check is first used.

Options:
  --depthview-output DIR   where failing image checks write their files
                           (default: <pytest basetemp>/depthview/<test id>/)
  --depthview-update-refs  create missing and rewrite differing reference images
                           (`service.image_check.assert_matches_reference`)

Fixtures (session-scoped):
  depthview_gl         one headless GL context on its own thread, as the service
                       runs it (service.testing.GLThread)
  depthview_render     render(scene, camera, effects=None) → the frame buffers
                       the service renders (service.testing.render_frame)
  depthview_reference  reference(scene, camera, effects=None) → the Embree
                       reference of the same frame (service.testing.reference_frame)

The assertions are `service.image_check.assert_images_close` and
`assert_matches_reference`.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest


class ImageCheckRun:
    """The image checks' view of one pytest session: its options, the test being
    run (set before its fixtures) and the reference images written."""

    def __init__(self, config: pytest.Config) -> None:
        self.config = config
        self.item: pytest.Item | None = None
        self.written: list[Path] = []
        self._names: dict[Path, set[str]] = {}
        self._claims: dict[Path, str] = {}      # reference image -> the test that checks it
        self._this_test: set[Path] = set()      # references the current test has checked
        self._cleared: set[Path] = set()        # output folders cleared of an earlier run's files

    @property
    def update_refs(self) -> bool:
        return bool(self.config.getoption("depthview_update_refs", False))

    def output_root(self) -> Path:
        opt = self.config.getoption("depthview_output", None)
        if opt:
            return Path(self.config.invocation_params.dir, opt)
        factory = getattr(self.config, "_tmp_path_factory", None)  # pytest's tmp_path_factory (tmpdir plugin)
        if factory is None:  # pragma: no cover - only with `-p no:tmpdir`
            import tempfile

            return Path(tempfile.mkdtemp(prefix="depthview-"))
        return factory.getbasetemp() / "depthview"

    def test_output_dir(self) -> Path:
        """The current test's folder for the files of failing checks."""
        from service.image_check import safe_name

        node = self.item.nodeid if self.item is not None else "outside-a-test"
        return self.output_root() / safe_name(node)

    def unique_name(self, folder: Path, base: str) -> str:
        """base, then base_2, base_3, ... for repeated checks of one test."""
        used = self._names.setdefault(folder, set())
        name, k = base, 1
        while name in used:
            k += 1
            name = f"{base}_{k}"
        used.add(name)
        return name

    def start(self, item: pytest.Item) -> None:
        """A test begins. With --depthview-output, the files an earlier run's failures
        left in its folder go, so the folder shows this run's failures only."""
        self.item = item
        self._this_test = set()
        if self.config.getoption("depthview_output", None):
            folder = self.test_output_dir()
            if folder not in self._cleared and folder.is_dir():  # two ids may share a folder: clear it once
                for old in folder.iterdir():
                    if _ARTIFACT.fullmatch(old.name):
                        old.unlink()
            self._cleared.add(folder)

    def claim(self, path: Path) -> None:
        """Note that the current test checks reference `path`, named after the test (no
        name= given); a ValueError when this test checked it already (two unnamed checks)
        or another test did (two test ids that make the same file name): each check needs
        a reference of its own. (References named explicitly may be shared on purpose.)"""
        key = path.with_suffix("").resolve()  # a PNG and an EXR of one name are one reference
        node = self.item.nodeid if self.item is not None else "outside-a-test"
        if key in self._this_test:
            raise ValueError(f"reference image {path} is checked twice by {node}: give each "
                             "assert_matches_reference of a test its own name=")
        owner = self._claims.setdefault(key, node)
        if owner != node:
            raise ValueError(f"reference image {path} is already the reference of {owner}; {node} makes the "
                             "same file name from its id: pass name= to tell them apart")
        self._this_test.add(key)

    def wrote(self, path: Path) -> Path:
        if path not in self.written:
            self.written.append(path)
        return path


#: Files a failing check writes (service.image_check: <name>_actual / _expected / _error / _bad).
_ARTIFACT = re.compile(r".+_(actual|expected|error|bad)\.(png|exr)")

_RUNS: list[ImageCheckRun] = []


def current_run() -> ImageCheckRun | None:
    """The innermost active pytest session's ImageCheckRun (None outside pytest)."""
    return _RUNS[-1] if _RUNS else None


def _run_of(config: pytest.Config) -> ImageCheckRun | None:
    return next((r for r in _RUNS if r.config is config), None)


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("depthview", "depthview image checks")
    group.addoption("--depthview-output", metavar="DIR", default=None,
                    help="folder for the files of failing image checks (default: <basetemp>/depthview)")
    group.addoption("--depthview-update-refs", action="store_true", default=False,
                    help="create missing and rewrite differing reference images of assert_matches_reference")


def pytest_configure(config: pytest.Config) -> None:
    _RUNS.append(ImageCheckRun(config))


def pytest_unconfigure(config: pytest.Config) -> None:
    run = _run_of(config)
    if run is not None:
        _RUNS.remove(run)


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item: pytest.Item) -> None:
    run = _run_of(item.config)
    if run is not None:
        run.start(item)


def pytest_terminal_summary(terminalreporter: Any, config: pytest.Config) -> None:
    run = _run_of(config)
    if run is None or not run.written:
        return
    terminalreporter.section("depthview: reference images written")
    for path in run.written:
        terminalreporter.line(str(path))
    terminalreporter.line(f"{len(run.written)} reference image(s) written: look at them, then commit them.")


@pytest.fixture(scope="session")
def depthview_gl() -> Iterator[Any]:
    """One headless GL context on its own thread (service.testing.GLThread)."""
    from service.testing import GLThread

    gl = GLThread()
    yield gl
    gl.close()


@pytest.fixture(scope="session")
def depthview_render(depthview_gl: Any) -> Callable[..., Any]:
    """render(scene, camera, effects=None) → the frame's buffers, rendered as the
    service renders them (service.testing.render_frame)."""
    from service.testing import render_frame

    def render(scene: Any, camera: Any, effects: Any = None) -> Any:
        return render_frame(depthview_gl, scene, camera, effects)

    return render


@pytest.fixture(scope="session")
def depthview_reference() -> Callable[..., Any]:
    """reference(scene, camera, effects=None) → the Embree reference of the same
    frame (service.testing.reference_frame)."""
    from service.testing import reference_frame

    return reference_frame

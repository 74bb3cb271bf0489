"""Old import paths of modules that moved into the layered packages (issue 19), kept for one release.

``import ilcnc.plan`` (or ``from ilcnc.simulate import simulate_program``) still
works: a finder on ``sys.meta_path`` answers the old name with the module at its
new place, after a :class:`DeprecationWarning` that names it. The same module
object serves both names, so a monkeypatch through the old path still reaches
the code. The table goes with the next release; new code imports the new paths
(``tests/test_architecture.py`` checks that ilcnc's own code does).
"""

from __future__ import annotations

import importlib
import importlib.machinery
import sys
import warnings
from types import ModuleType

__all__ = ["MOVED", "install"]

#: Old module (under ``ilcnc.``) -> its place now.
MOVED: dict[str, str] = {
    "air": "contour.air",
    "batch": "shop.batch",
    "command_error": "vcnc.command_error",
    "corrections": "shop.corrections",
    "deflection": "vcnc.deflection",
    "drives": "vcnc.drives",
    "export": "shop.export",
    "feed": "learning.feed",
    "fidelity": "shop.fidelity",
    "identify": "learning.identify",
    "inspect": "shop.inspect",
    "laws": "learning.laws",
    "learn": "learning.learner",
    "lifted_error": "vcnc.lifted",
    "linuxcnc": "shop.linuxcnc",
    "logs": "axislog.log",
    "machine_errors": "vcnc.machine_errors",
    "measure": "shop.measure",
    "plan": "vcnc.plan",
    "plan_tp": "vcnc.plan_tp",
    "profile_edit": "profile.edit",
    "refine": "learning.refine",
    "report": "shop.report",
    "simulate": "vcnc.simulate",
    "state": "shop.state",
    "stream": "vcnc.stream",
    "tune": "learning.tune",
    "volumetric": "vcnc.volumetric",
    "workflow": "shop.workflow",
}


class _Alias:
    """The loader of an old name (the protocol of :class:`importlib.abc.Loader`: importing that module, with
    ``importlib.resources``, ``tempfile`` and ``shutil``, took 4-16 ms of every command's start-up, issue 24)."""

    def __init__(self, new: str) -> None:
        self.new = new

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType:
        warnings.warn(f"{spec.name} moved to {self.new}; the old path goes with the next release",
                      DeprecationWarning, stacklevel=2)
        return importlib.import_module(self.new)

    def exec_module(self, module: ModuleType) -> None:
        """The module at its new place is already executed."""


class _MovedFinder:
    """The finder of the old names (the protocol of :class:`importlib.abc.MetaPathFinder`)."""

    def find_spec(self, fullname: str, path: object = None, target: object = None
                  ) -> importlib.machinery.ModuleSpec | None:
        head, _, tail = fullname.partition(".")
        if head != "ilcnc" or tail not in MOVED:
            return None
        return importlib.machinery.ModuleSpec(fullname, _Alias("ilcnc." + MOVED[tail]))


def install() -> None:
    """Put the finder on ``sys.meta_path`` (once)."""
    if not any(isinstance(f, _MovedFinder) for f in sys.meta_path):
        sys.meta_path.append(_MovedFinder())

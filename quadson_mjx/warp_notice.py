"""mujoco.mjx prints "Failed to import warp" and "Failed to import mujoco_warp" when it is imported
without warp-lang installed: to every user of every command, though only the warp backend
(env.impl="warp") needs it. `install` (run by quadson_mjx/__init__.py) makes that one submodule's
import quiet and keeps what it printed; `require_warp` reports it to a user who asks for warp.

If mujoco.mjx was imported before quadson_mjx, its messages were printed already; nothing changes.
Imports nothing heavy: the robot's control loop imports the package too.
"""

from __future__ import annotations

import contextlib
import importlib.abc
import importlib.machinery
import io
import sys

MODULE = "mujoco.mjx.warp"  # the submodule of mujoco.mjx that prints when warp is missing
captured: list[str] = []  # what its import printed


class _QuietLoader(importlib.abc.Loader):
    def __init__(self, loader):
        self._loader = loader

    def create_module(self, spec):
        return self._loader.create_module(spec)

    def exec_module(self, module):
        out = io.StringIO()
        with contextlib.redirect_stdout(out):
            self._loader.exec_module(module)
        captured.append(out.getvalue())


class _Finder(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name != MODULE:
            return None
        spec = importlib.machinery.PathFinder.find_spec(name, path)
        if spec is not None and spec.loader is not None:
            spec.loader = _QuietLoader(spec.loader)
        return spec


def install() -> None:
    """Quiets mujoco.mjx's warp import from now on (idempotent)."""
    if not any(isinstance(f, _Finder) for f in sys.meta_path):
        sys.meta_path.insert(0, _Finder())


def require_warp() -> None:
    """Raises ValueError with the import errors when the warp backend cannot run. mujoco.mjx carries
    its own copy of MuJoCo Warp (mujoco.mjx.third_party); only warp-lang comes from outside."""
    try:
        import warp  # noqa: F401
        from mujoco.mjx.third_party import mujoco_warp  # noqa: F401
    except (ImportError, RuntimeError) as e:
        said = " ".join(line.strip() for text in captured for line in text.splitlines() if line.strip())
        raise ValueError(
            f"env.impl='warp' needs warp-lang ({e}{'; ' + said if said else ''}); "
            "install it (pip install warp-lang) or use env.impl=jax"
        ) from None

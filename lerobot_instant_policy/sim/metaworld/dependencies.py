"""What the MetaWorld env needs beyond the base install, checked with one-line errors before anything renders.

* the ``metaworld`` extra (``pip install -e '.[metaworld]'``): ``metaworld==3.0.0`` and ``mujoco<3.4`` (with mujoco
  3.4 and later MetaWorld 3.0.0's ``reset()`` fails in ``reset_mocap_welds``: "could not broadcast input array from
  shape (11,) into shape (12,)");
* an OpenGL library for MuJoCo's offscreen rendering. ``MUJOCO_GL`` defaults to ``osmesa`` (software rendering,
  Debian's ``libosmesa6``), the one backend that rendered depth headless on these machines (``egl`` failed); set
  ``MUJOCO_GL`` yourself to use another.

:func:`import_metaworld` sets that default, checks both and imports ``metaworld``; call it before ``mujoco`` or
``metaworld`` is imported anywhere in the process (MuJoCo reads ``MUJOCO_GL`` once, when it is imported).
"""

from __future__ import annotations

import ctypes.util
import importlib
import importlib.metadata
import os
import sys

DEFAULT_MUJOCO_GL = "osmesa"
MUJOCO_VERSION_LIMIT = (3, 4)  # MetaWorld 3.0.0 fails to reset with mujoco 3.4 and later
_INSTALL = "pip install -e '.[metaworld]' (metaworld==3.0.0, mujoco<3.4)"
#: the shared library each MUJOCO_GL backend loads, and the Debian package that provides it
GL_LIBRARIES = {"osmesa": ("OSMesa", "libosmesa6"), "egl": ("EGL", "libegl1")}


class MetaworldSetupError(RuntimeError):
    """The ``metaworld`` extra or the OpenGL library MuJoCo renders with is missing (the message says which)."""


def import_metaworld():
    """The ``metaworld`` module, after setting ``MUJOCO_GL`` (default ``osmesa``) and checking the extra and the GL
    library; raises :class:`MetaworldSetupError` with a one-line message otherwise."""
    if "MUJOCO_GL" not in os.environ and "mujoco" in sys.modules:
        raise MetaworldSetupError(
            "mujoco was imported before MUJOCO_GL was set and chose its windowed backend: set MUJOCO_GL=osmesa in the "
            "environment (or import the MetaWorld env before mujoco)"
        )
    os.environ.setdefault("MUJOCO_GL", DEFAULT_MUJOCO_GL)
    if os.environ["MUJOCO_GL"] == "osmesa":
        os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")
    check_mujoco_version()
    check_gl_library()
    try:
        return importlib.import_module("metaworld")
    except ImportError as error:
        raise MetaworldSetupError(f"the MetaWorld env needs the metaworld extra ({error}): {_INSTALL}") from error


def check_mujoco_version() -> None:
    """Raise :class:`MetaworldSetupError` when mujoco is missing or too new for MetaWorld 3.0.0."""
    try:
        version = importlib.metadata.version("mujoco")
    except importlib.metadata.PackageNotFoundError as error:
        raise MetaworldSetupError(f"the MetaWorld env needs the metaworld extra (mujoco is not installed): {_INSTALL}") from error
    major_minor = tuple(int(part) for part in version.split(".")[:2])
    if major_minor >= MUJOCO_VERSION_LIMIT:
        raise MetaworldSetupError(
            f"mujoco {version} breaks MetaWorld 3.0.0's reset (reset_mocap_welds); install mujoco<3.4: {_INSTALL}"
        )


def check_gl_library() -> None:
    """Raise :class:`MetaworldSetupError` when the shared library of ``MUJOCO_GL``'s backend cannot be found."""
    backend = os.environ.get("MUJOCO_GL", DEFAULT_MUJOCO_GL)
    if backend not in GL_LIBRARIES:
        return  # glfw or another backend: MuJoCo reports its own errors
    library, package = GL_LIBRARIES[backend]
    if ctypes.util.find_library(library) is None:
        raise MetaworldSetupError(
            f"MUJOCO_GL={backend} needs the {library} library for MuJoCo's offscreen rendering: "
            f"apt-get install {package} (or set MUJOCO_GL to a backend this machine has)"
        )

"""Where numba keeps the compiled kernels, so that a read-only install starts warm (no ROS).

numba caches machine code beside each source file (``__pycache__``) when it can write there:
a venv, a symlink install, or an install tree written at build time. The colcon install
compiles every kernel into its own tree once (``setup.py``'s install step runs
:mod:`ekf_localization.tools.warm_kernels`). A user who cannot write that tree would make
numba fall back to an empty user-wide cache and compile everything again (about 30 s of CPU
at the first start). :func:`configure` points numba at a cache under the user's
``$XDG_CACHE_HOME`` (``~/.cache``) instead, seeded from the tree's compiled files. numba
keys each entry by a hash of its source's content, so the copies stay valid, and a changed
source recompiles as usual.

``NUMBA_CACHE_DIR``, when set, always wins.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import sys
from pathlib import Path

_ROOT = Path(__file__).resolve().parents[2]  # the folder holding ekf_localization/ and sim_robot/
KERNEL_PACKAGES = ("ekf_localization", "sim_robot")


def user_cache_dir(environ: os._Environ | dict = os.environ) -> Path:
    """``$XDG_CACHE_HOME/ekf_localization/numba`` (``~/.cache`` when unset)."""
    base = environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "ekf_localization" / "numba"


def numba_subpath(source_dir: Path) -> str:
    """numba's name for a source folder inside ``NUMBA_CACHE_DIR`` (its
    ``_CacheLocator.get_suitable_cache_subpath``: the folder's name and a SHA-1 of its path)."""
    path = os.path.abspath(source_dir)
    return f"{os.path.basename(path)}_{hashlib.sha1(path.encode()).hexdigest()}"


def in_tree_caches(root: Path = _ROOT) -> list[Path]:
    """The ``__pycache__`` folders of the kernel packages that hold numba cache files."""
    out = []
    for pkg in KERNEL_PACKAGES:
        for cache in sorted((root / pkg).rglob("__pycache__")):
            if any(cache.glob("*.nbi")):
                out.append(cache)
    return out


def tree_is_writable(root: Path = _ROOT) -> bool:
    """Whether numba can write the in-tree caches (it tries a temporary file, as here)."""
    import tempfile

    target = root / "ekf_localization" / "core" / "__pycache__"
    try:
        target.mkdir(exist_ok=True)
        tempfile.TemporaryFile(dir=target).close()
    except OSError:
        return False
    return True


def seed(cache_dir: Path, root: Path = _ROOT) -> int:
    """Copy the tree's compiled kernels into ``cache_dir`` in numba's layout; the number of files."""
    copied = 0
    for cache in in_tree_caches(root):
        dest = cache_dir / numba_subpath(cache.parent)
        dest.mkdir(parents=True, exist_ok=True)
        for f in cache.iterdir():
            if f.suffix not in (".nbi", ".nbc"):
                continue
            out = dest / f.name
            if not out.exists() or out.stat().st_mtime < f.stat().st_mtime:  # new, or a rebuilt tree
                shutil.copy2(f, out)
                copied += 1
    return copied


def configure(environ: os._Environ | dict = os.environ, root: Path = _ROOT) -> Path | None:
    """Set ``NUMBA_CACHE_DIR`` to a seeded user cache when the tree is not writable.

    Returns the cache folder set, or None when numba's own choice stands (``NUMBA_CACHE_DIR``
    already set, or a writable tree). Never raises: without a usable cache numba compiles.
    """
    if environ.get("NUMBA_CACHE_DIR") or tree_is_writable(root):
        return None
    cache_dir = user_cache_dir(environ)
    try:
        cache_dir.mkdir(parents=True, exist_ok=True)
        seed(cache_dir, root)
    except OSError:
        return None
    environ["NUMBA_CACHE_DIR"] = str(cache_dir)
    numba_config = sys.modules.get("numba.core.config")
    if numba_config is not None:  # numba was imported first: its config has read the variable already
        numba_config.CACHE_DIR = str(cache_dir)
    return cache_dir

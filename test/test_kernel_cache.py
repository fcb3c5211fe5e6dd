"""The numba cache location for read-only installs (core/kernel_cache.py)."""

from __future__ import annotations

import os
from pathlib import Path

from numba.core.caching import _CacheLocator

from ekf_localization.core import kernel_cache


def _tree(root: Path) -> Path:
    cache = root / "ekf_localization" / "core" / "__pycache__"
    cache.mkdir(parents=True)
    (cache / "kernels.predict-10.py311.nbi").write_bytes(b"index")
    (cache / "kernels.predict-10.py311.1.nbc").write_bytes(b"code")
    (cache / "kernels.cpython-311.pyc").write_bytes(b"bytecode")
    return cache


def test_subpath_is_numbas_own(tmp_path):
    src = tmp_path / "pkg" / "mod.py"
    assert kernel_cache.numba_subpath(src.parent) == _CacheLocator.get_suitable_cache_subpath(str(src))


def test_seed_copies_numba_files_in_numbas_layout(tmp_path):
    cache = _tree(tmp_path / "root")
    out = tmp_path / "user"
    assert kernel_cache.seed(out, tmp_path / "root") == 2
    dest = out / kernel_cache.numba_subpath(cache.parent)
    assert sorted(p.name for p in dest.iterdir()) == ["kernels.predict-10.py311.1.nbc",
                                                       "kernels.predict-10.py311.nbi"]
    assert kernel_cache.seed(out, tmp_path / "root") == 0  # already there
    later = cache / "kernels.predict-10.py311.nbi"  # a rebuilt tree: newer files are copied again
    os.utime(later, (later.stat().st_mtime + 10, later.stat().st_mtime + 10))
    assert kernel_cache.seed(out, tmp_path / "root") == 1


def test_configure_points_numba_at_a_seeded_user_cache(tmp_path, monkeypatch):
    root = tmp_path / "root"
    _tree(root)
    env = {"XDG_CACHE_HOME": str(tmp_path / "xdg")}
    monkeypatch.setattr(kernel_cache, "tree_is_writable", lambda _root: False)
    got = kernel_cache.configure(env, root)
    assert got == tmp_path / "xdg" / "ekf_localization" / "numba"
    assert env["NUMBA_CACHE_DIR"] == str(got)
    assert any(got.rglob("*.nbi"))


def test_configure_leaves_numba_alone_when_it_can_write_or_is_told(tmp_path, monkeypatch):
    root = tmp_path / "root"
    _tree(root)
    env: dict[str, str] = {}
    assert kernel_cache.configure(env, root) is None  # a writable tree: numba's in-tree cache
    assert "NUMBA_CACHE_DIR" not in env
    monkeypatch.setattr(kernel_cache, "tree_is_writable", lambda _root: False)
    env = {"NUMBA_CACHE_DIR": str(tmp_path / "mine")}
    assert kernel_cache.configure(env, root) is None
    assert env["NUMBA_CACHE_DIR"] == str(tmp_path / "mine")

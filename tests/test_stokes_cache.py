"""The Stokes unit-flow cache: a user cache folder keyed by the mesh's content, atomic writes,
validation on reading (damaged files are rebuilt with a warning), and runs that survive an
unwritable cache folder."""

import warnings
from pathlib import Path

import numpy as np
import pytest

from femphase.cli import main
from femphase.config import Numerics
from femphase.domains.mesh import stokes
from femphase.domains.mesh.domain import MeshDomain
from femphase.domains.mesh.stokes import StokesCacheWarning, cache_dir, cache_path, domain_stokes_flow
from femphase.testing.fuzzing import MESH_FILE, MESH_SCENE, mesh_files, to_toml

SPEC = {"type": "stokes", "max_velocity": 0.1}


@pytest.fixture
def mesh_dir(tmp_path):
    folder = tmp_path / "meshes"
    folder.mkdir()
    (folder / MESH_FILE).write_bytes(mesh_files()[MESH_FILE])
    return folder


@pytest.fixture
def cache(tmp_path, monkeypatch):
    folder = tmp_path / "cache"
    monkeypatch.setenv("FEMPHASE_CACHE", str(folder))
    return folder


def domain(folder: Path) -> MeshDomain:
    """A fresh domain (no in-memory solutions) read from the mesh file in ``folder``."""
    return MeshDomain.from_table({"kind": "mesh", "mesh": MESH_FILE}, folder, Numerics())


def solved(folder: Path):
    """The flow of SPEC, with no warning allowed."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return domain_stokes_flow(domain(folder), SPEC)


def no_solving(monkeypatch):
    def refuse(*args, **kwargs):
        raise AssertionError("the flow was solved although the cache holds it")

    monkeypatch.setattr(stokes, "solve_stokes", refuse)


def test_cache_folder_follows_the_environment(tmp_path, monkeypatch):
    monkeypatch.delenv("FEMPHASE_CACHE", raising=False)
    monkeypatch.delenv("XDG_CACHE_HOME", raising=False)
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert cache_dir() == tmp_path / "home" / ".cache" / "femphase"
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cache_dir() == tmp_path / "xdg" / "femphase"
    monkeypatch.setenv("FEMPHASE_CACHE", str(tmp_path / "mine"))
    assert cache_dir() == tmp_path / "mine"
    monkeypatch.setenv("FEMPHASE_CACHE", "")  # empty counts as unset
    assert cache_dir() == tmp_path / "xdg" / "femphase"


def test_solution_is_cached_by_content_not_path(tmp_path, mesh_dir, cache, monkeypatch):
    first = solved(mesh_dir)
    files = sorted(cache.iterdir())
    assert [f.name for f in files] == [cache_path(domain(mesh_dir)).name]
    assert not list(mesh_dir.glob("*.npz")), "nothing is written beside the mesh"
    # the same mesh elsewhere finds the same file; nothing is solved again
    moved = tmp_path / "elsewhere"
    moved.mkdir()
    (moved / MESH_FILE).write_bytes((mesh_dir / MESH_FILE).read_bytes())
    no_solving(monkeypatch)
    again = solved(moved)
    np.testing.assert_array_equal(again.velocity, first.velocity)
    assert sorted(cache.iterdir()) == files
    # another viscosity is another file
    assert cache_path(domain(mesh_dir), 2.0) != cache_path(domain(mesh_dir), 1.0)


@pytest.mark.parametrize("damage", ["corrupt", "truncated", "empty", "other mesh", "wrong shape"])
def test_damaged_cache_is_rebuilt_with_a_warning(mesh_dir, cache, damage):
    reference = solved(mesh_dir)
    path = cache_path(domain(mesh_dir))
    data = path.read_bytes()
    if damage == "corrupt":
        path.write_bytes(bytes((b * 37 + 11) % 256 for b in data))
    elif damage == "truncated":
        path.write_bytes(data[: len(data) // 2])
    elif damage == "empty":
        path.write_bytes(b"")
    else:
        with np.load(path) as stored:
            arrays = dict(stored)
        if damage == "other mesh":
            arrays["checksum"] = np.array("0" * 64)
        else:
            arrays["velocity"] = arrays["velocity"][:-3]
        np.savez(path, **arrays)
    with pytest.warns(StokesCacheWarning, match=str(path.name)):
        rebuilt = domain_stokes_flow(domain(mesh_dir), SPEC)
    np.testing.assert_allclose(rebuilt.velocity, reference.velocity, rtol=1e-12, atol=1e-15)
    assert rebuilt.flux == pytest.approx(reference.flux)
    # the file was replaced by a good one: read back silently
    np.testing.assert_array_equal(solved(mesh_dir).velocity, rebuilt.velocity)
    assert not list(cache.glob(".*.tmp")), "no temporary file is left behind"


@pytest.mark.parametrize("where", ["parent is a file", "under /proc"])
def test_unwritable_cache_folder_only_warns(tmp_path, mesh_dir, monkeypatch, where):
    if where == "parent is a file":
        blocker = tmp_path / "blocker"
        blocker.write_text("a regular file, not a folder\n")
        folder = blocker / "cache"
    else:
        folder = Path("/proc/femphase-cache-test")
    monkeypatch.setenv("FEMPHASE_CACHE", str(folder))
    with pytest.warns(StokesCacheWarning, match="cannot write the Stokes cache"):
        flow = domain_stokes_flow(domain(mesh_dir), SPEC)
    assert np.hypot(*flow.velocity_at_nodes()).max() == pytest.approx(0.1)
    assert not folder.exists()


def test_a_run_survives_an_unwritable_cache(tmp_path, mesh_dir, monkeypatch, capsys):
    blocker = tmp_path / "blocker"
    blocker.write_text("a regular file\n")
    monkeypatch.setenv("FEMPHASE_CACHE", str(blocker / "cache"))
    scene = mesh_dir / "scene.toml"
    scene.write_text(to_toml(MESH_SCENE))
    code = main(["run", str(scene), "-o", str(tmp_path / "run"), "-q"])
    err = capsys.readouterr().err
    assert code == 0, err
    assert "femphase: warning:" in err and "cannot write the Stokes cache" in err
    assert "Traceback" not in err
    assert (tmp_path / "run" / "checkpoint.h5").is_file()


def test_a_damaged_cache_in_a_run_is_rebuilt(tmp_path, mesh_dir, cache, capsys):
    solved(mesh_dir)
    path = cache_path(domain(mesh_dir))
    path.write_bytes(path.read_bytes()[:100])
    scene = mesh_dir / "scene.toml"
    scene.write_text(to_toml(MESH_SCENE))
    code = main(["run", str(scene), "-o", str(tmp_path / "run"), "-q"])
    err = capsys.readouterr().err
    assert code == 0, err
    assert "femphase: warning:" in err and path.name in err and "Traceback" not in err
    solved(mesh_dir)  # rewritten: no warning now

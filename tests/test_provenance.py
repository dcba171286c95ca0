"""provenance.versions: the source tree's git revision and whether its tracked files match it."""

import subprocess

from quadson_mjx import provenance


def _git(repo, *args):
    subprocess.run(["git", *args], cwd=repo, check=True, capture_output=True)


def test_git_revision_and_tree_state(tmp_path):
    assert provenance.versions(tmp_path)["git_revision"] == "unknown"  # no repository
    assert provenance.versions(tmp_path)["git_tree"] == "unknown"
    _git(tmp_path, "init", "-q")
    (tmp_path / "a.py").write_text("x = 1\n")
    _git(tmp_path, "add", "a.py")
    _git(tmp_path, "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "one")
    head = subprocess.run(
        ["git", "rev-parse", "HEAD"], cwd=tmp_path, capture_output=True, text=True
    ).stdout.strip()
    v = provenance.versions(tmp_path)
    assert v["git_revision"] == head and len(head) == 40
    assert v["git_tree"] == "clean"
    (tmp_path / "b.py").write_text("untracked\n")  # an untracked file is not the run's code
    assert provenance.versions(tmp_path)["git_tree"] == "clean"
    (tmp_path / "a.py").write_text("x = 2\n")  # an edited tracked file is
    v = provenance.versions(tmp_path)
    assert v["git_revision"] == head and v["git_tree"] == "modified"
    assert {"python", "jax", "brax", "mujoco", "numpy", "devices"} <= v.keys()


def test_versions_name_the_matmul_precision():
    import jax

    assert provenance.versions()["matmul_precision"] == "default"  # the test session sets none
    with jax.default_matmul_precision("highest"):
        assert provenance.versions()["matmul_precision"] == "highest"

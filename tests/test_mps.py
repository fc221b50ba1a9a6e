"""factory.mps: when a job starts an MPS daemon of its own, and that a daemon which does not come up
is stopped and leaves nothing behind. (The daemon's success path needs an NVIDIA GPU; it is
measured on the lent GPU machines, docs/guides/gpus-and-clusters.md.)"""

from __future__ import annotations

import os
import stat
import textwrap

import pytest

from factory import gpus, mps


@pytest.fixture
def clean_env(monkeypatch):
    for k in (mps.MODE_ENV, mps.PIPE_ENV, mps.LOG_ENV):
        monkeypatch.delenv(k, raising=False)
    return monkeypatch


def test_mode_comes_from_the_flag_then_the_environment_and_bad_values_list_the_choices(clean_env):
    assert mps.mode_of() == "auto"
    clean_env.setenv(mps.MODE_ENV, "OFF")
    assert mps.mode_of() == "off"
    assert mps.mode_of("auto") == "auto"
    with pytest.raises(ValueError, match="auto, off"):
        mps.mode_of("always")
    clean_env.setenv(mps.MODE_ENV, "sometimes")
    with pytest.raises(ValueError, match=mps.MODE_ENV):
        mps.mode_of()


def test_plan_says_why_no_daemon_is_started(clean_env):
    clean_env.setattr(gpus, "count", lambda: 0)
    assert mps.plan(16) == mps.Sharing(False, "no NVIDIA GPU")
    clean_env.setattr(gpus, "count", lambda: 2)
    assert "one process per GPU" in mps.plan(2).why
    assert "more than the 48" in mps.plan(2 * 49).why
    assert "off" in mps.plan(16, "off").why and not mps.plan(16, "off").mps
    clean_env.setenv("PATH", "/nonexistent")
    assert mps.CONTROL in mps.plan(16).why
    clean_env.setenv(mps.PIPE_ENV, "/tmp/theirs")
    users = mps.plan(16)
    assert users.mps and "/tmp/theirs" in users.why


def _stand_in_control(folder) -> None:
    """An `nvidia-cuda-mps-control` that makes its control pipe and answers commands, where no
    driver is (this machine): the probe's CUDA context then fails, as on a machine whose MPS
    server cannot start."""
    script = folder / mps.CONTROL
    script.write_text(textwrap.dedent("""\
        #!/bin/sh
        if [ "$1" = "-f" ]; then
            echo $$ > "$STAND_IN_PID"
            : > "$CUDA_MPS_PIPE_DIRECTORY/control"
            echo "started" > "$CUDA_MPS_LOG_DIRECTORY/control.log"
            while [ ! -e "$CUDA_MPS_PIPE_DIRECTORY/quit" ]; do sleep 0.05; done
            exit 0
        fi
        read command
        [ "$command" = "quit" ] && : > "$CUDA_MPS_PIPE_DIRECTORY/quit"
        exit 0
        """))
    script.chmod(script.stat().st_mode | stat.S_IEXEC)


def test_a_daemon_whose_server_does_not_come_up_is_stopped_and_leaves_nothing(clean_env, tmp_path):
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    _stand_in_control(bin_dir)
    clean_env.setenv("PATH", f"{bin_dir}{os.pathsep}{os.environ['PATH']}")
    clean_env.setenv("TMPDIR", str(tmp_path))
    clean_env.setenv("STAND_IN_PID", str(tmp_path / "daemon.pid"))
    clean_env.setattr(gpus, "count", lambda: 1)
    clean_env.setattr(mps, "_daemon_running", lambda: False)
    import tempfile

    clean_env.setattr(tempfile, "tempdir", None)  # so mkdtemp reads TMPDIR
    assert mps.plan(4) is None
    lines = []
    with mps.shared_gpu(4, say=lines.append) as sharing:
        assert not sharing.mps
        assert mps.PIPE_ENV not in os.environ  # the workers started here would not look for it
    assert "MPS not started" in lines[0] and "its log ends: started" in lines[0], lines
    assert not [p for p in tmp_path.iterdir() if p.name.startswith("brick-factory-mps-")]
    daemon = int((tmp_path / "daemon.pid").read_text())
    assert not os.path.exists(f"/proc/{daemon}") or "Z" in open(f"/proc/{daemon}/stat").read().split()[2]


def test_no_gpu_leaves_the_environment_alone(clean_env):
    clean_env.setattr(gpus, "count", lambda: 0)
    before = dict(os.environ)
    lines = []
    with mps.shared_gpu(16, say=lines.append) as sharing:
        assert sharing == mps.Sharing(False, "no NVIDIA GPU")
    assert dict(os.environ) == before and lines == ["gpu sharing: no NVIDIA GPU"]


def test_a_build_asks_for_mps_only_for_the_batched_checks_in_local_processes(clean_env):
    """`pipelines.dataset.build`: the growers of a lockstep build with the 'jax' checks (or every
    worker without lockstep) are the clients; the CPU reference and Ray tasks ask for nothing."""
    from factory.sampler import SamplerConfig
    from pipelines.dataset.build import _gpu_sharing
    from pipelines.dataset.config import DatasetConfig

    asked = []
    clean_env.setattr(mps, "shared_gpu", lambda clients, mode: asked.append((clients, mode)) or "sharing")
    batched = DatasetConfig("synthetic", 4, seed=0, sampler=SamplerConfig(seed=0, backend="jax"))
    assert _gpu_sharing(batched, "local", 12, 16, None, None) == "sharing"  # 8 growers of 12 workers
    assert _gpu_sharing(batched, "local", 12, 16, 5, "off") == "sharing"
    assert _gpu_sharing(batched, "local", 6, 1, None, None) == "sharing"  # every worker grows its own
    assert asked == [(8, None), (5, "off"), (6, None)]
    reference = DatasetConfig("synthetic", 4, seed=0)
    for config, runner in ((reference, "local"), (batched, "ray")):
        with _gpu_sharing(config, runner, 12, 16, None, None) as got:
            assert got is None
    assert len(asked) == 3

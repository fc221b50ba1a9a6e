"""What a build ran on and used (`pipelines.dataset.usage`): the host's CPU and GPU models, and the
GPU sampler. CI has no GPU, so the sampler is driven here by a stand-in `nvidia-smi` that prints
the same CSV lines; on a GPU machine every build runs the real one (docs/guides/build-a-dataset.md)."""

from __future__ import annotations

import os
import platform
import subprocess
import sys
import textwrap
import time

from factory import gpus
from pipelines.dataset import usage
from process_support import assert_workers_end_with_killed_parent


def test_the_cpu_model_is_the_first_model_name_the_kernel_lists(tmp_path):
    info = tmp_path / "cpuinfo"
    info.write_text("processor\t: 0\nvendor_id\t: GenuineIntel\nmodel name\t: Intel(R) Xeon(R) Processor\n\n"
                    "processor\t: 1\nmodel name\t: Other\n")
    assert usage.cpu_model(str(info)) == "Intel(R) Xeon(R) Processor"
    assert usage.cpu_model(str(tmp_path / "missing")) == (platform.processor() or platform.machine())
    if os.path.exists("/proc/cpuinfo"):
        names = [line.split(":", 1)[1].strip() for line in open("/proc/cpuinfo") if line.startswith("model name")]
        assert not names or usage.cpu_model() == names[0]


def test_gpu_models_come_from_the_driver_folder_in_its_order(tmp_path):
    for bus, model in (("0000:c1:00.0", "NVIDIA H200"), ("0000:41:00.0", "NVIDIA H100 80GB HBM3")):
        (tmp_path / bus).mkdir()
        (tmp_path / bus / "information").write_text(
            f"Model: \t\t {model}\nIRQ:   \t\t 42\nGPU UUID: \t GPU-0\nBus Location: \t {bus}\n")
    assert gpus.models(str(tmp_path)) == ["NVIDIA H100 80GB HBM3", "NVIDIA H200"]
    assert gpus.models(str(tmp_path / "none")) == []


def test_a_sample_line_is_read_as_nvidia_smi_prints_it():
    assert usage.parse_sample("0, 47, 16501\n") == (0, 47.0, 16501.0)
    assert usage.parse_sample("1, [N/A], 12") is None
    assert usage.parse_sample("index, utilization.gpu [%], memory.used [MiB]") is None
    assert usage.parse_sample("") is None


def test_nothing_is_sampled_without_a_gpu_or_a_sampler():
    with usage.GpuWatch(gpus=[]) as watch:
        pass
    assert watch.report() is None and watch.why_not == "no NVIDIA GPU"
    with usage.GpuWatch(gpus=["NVIDIA H200"], command="/nonexistent/nvidia-smi") as watch:
        pass
    assert watch.report() is None and watch.why_not.startswith("nvidia-smi did not start")


def _stand_in(tmp_path, rows):
    """An executable that prints `rows` as `nvidia-smi --query-gpu=QUERY` would, then samples on."""
    fake = tmp_path / "nvidia-smi"
    fake.write_text(textwrap.dedent(f"""\
        #!{sys.executable}
        import sys, time
        assert "--query-gpu={usage.QUERY}" in sys.argv and "--format=csv,noheader,nounits" in sys.argv
        for r in {rows!r}:
            print(", ".join(r), flush=True)
        time.sleep(60)  # sampling goes on until the watch ends it
        """))
    fake.chmod(0o755)
    return fake


def test_a_killed_build_leaves_no_sampler_running(tmp_path):
    fake = _stand_in(tmp_path, [("0", "1", "2")])
    code = (f"from pipelines.dataset import usage\nimport time\n"
            f"with usage.GpuWatch(command={str(fake)!r}, gpus=['A']):\n    time.sleep(120)\n")
    proc = subprocess.Popen([sys.executable, "-c", code], cwd=str(tmp_path),
                            env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)})
    assert_workers_end_with_killed_parent(proc, str(fake).encode(), workers=1)


def test_the_watch_keeps_each_gpus_mean_use_and_peak_memory(tmp_path):
    fake = _stand_in(tmp_path, [("0", "10", "100"), ("1", "[N/A]", "7"), ("0", "30", "300"), ("1", "50", "5")])
    with usage.GpuWatch(command=str(fake), gpus=["A", "B"]) as watch:
        deadline = time.monotonic() + 20
        while sum(len(v) for v in watch._samples.values()) < 3 and time.monotonic() < deadline:
            time.sleep(0.05)
    assert watch._proc.poll() is not None  # ended with the block
    assert watch.report() == [
        {"index": 0, "busy_mean_pct": 20.0, "memory_max_mib": 300, "samples": 2},
        {"index": 1, "busy_mean_pct": 50.0, "memory_max_mib": 5, "samples": 1},
    ]
    assert watch.why_not is None
    line = usage.describe({"host": {"cpu_model": "X", "logical_cpus": 16, "gpus": ["A", "B"]},
                           "cpu_seconds": {"user": 100.4, "system": 20.2}, "gpus": watch.report()})
    assert line == ("CPU 121 s (system 20) on 16 x X; GPU 0 busy 20 % (mean), 300 MiB peak, "
                    "GPU 1 busy 50 % (mean), 5 MiB peak")

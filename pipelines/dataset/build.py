"""Run a build: check the folder against the config, run the missing shards (in this process, in
local worker processes or as Ray tasks), then write `meta/info.json`, the dataset card and the
gallery from the completion markers and the data files.

    from pipelines.dataset import DatasetConfig, build
    summary = build(config, "out/synth", runner="local", workers=2)

Every source is built this way: sampled objects and human designs (the builder makes their
source from the config), and world feedback (`pipelines.feedback` gives its source: it reads a
model's answers through `eval`, which the builder does not import).
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import socket
import sys
import time
from concurrent.futures import as_completed
from contextlib import ExitStack, contextmanager
from importlib import metadata
from pathlib import Path

from tqdm import tqdm

from factory import mps
from factory.atomic import write_atomic
from factory.dataset.info import Counts, DatasetInfo, json_bytes, write_info
from factory.dataset.tasks import FEEDBACK_IMAGES, SPLITS
from factory.errors import LDrawError
from factory.physics.decompose import COACD_SECONDS_ENV
from factory.sampler.config import RUN_SETTINGS
from factory.sampler.sampler import target_steps
from pipelines.dataset.config import (ConfigMismatchError, DatasetConfig, diff_configs, record_hash, started_hash,
                                      started_record)
from pipelines.dataset import cluster, spool, usage
from pipelines.dataset.card import dataset_card
from pipelines.dataset.gallery import write_gallery
from pipelines.dataset.shards import (build_shard, folder_identity, marker_path, object_source, read_marker,
                                      remove_stranded)
from pipelines.workers import ONE_THREAD, one_thread_each
from pipelines.workers import pool as workers_pool

RUNNERS = ("local", "ray")
"""Where a build's shards run: worker processes of this machine, or Ray tasks."""
PACKAGES = ("brick-factory", "numpy", "scipy", "trimesh", "mujoco", "pillow", "pyarrow")
ENV_FOR_WORKERS = ("PYTHONPATH", "MUJOCO_GL", "BRICK_FACTORY_CACHE", "LDRAWDIR", "BRICK_RENDER_SAMPLES",
                   COACD_SECONDS_ENV)


class ShardFailedError(RuntimeError):
    pass


class ShardInputError(ShardFailedError):
    """Every failed shard failed on its input (an LDraw error: a bad model or part, a model past a
    checker's budget), which a re-run cannot fix: the command exits 2, as for bad input found
    before the build."""


class FolderBusyError(RuntimeError):
    """Another run is building the same output folder."""


@contextmanager
def holding(out):
    """Hold `out` for one build: an exclusive `flock` on `OUT/meta/build.lock`, which names the
    holder (pid, host, start). A second run on the folder is refused (`FolderBusyError`) instead of
    deleting the first's temporary files; the lock ends with the holding process however it ends,
    and the file is removed when the build ends, so a finished folder holds no trace of it."""
    path = Path(out) / "meta" / "build.lock"
    path.parent.mkdir(parents=True, exist_ok=True)
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            try:
                holder = os.pread(fd, 512, 0).decode(errors="replace").strip() or "a run starting"
            finally:
                os.close(fd)
            raise FolderBusyError(f"{out} is being built by another run ({holder}); wait for it to end, "
                                  "or use another output folder") from None
        # The previous holder may have removed the file between our open and our lock: then we
        # hold a lock on a file no one else sees; take the one at the path instead.
        try:
            same = os.fstat(fd).st_ino == os.stat(path).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"pid {os.getpid()} on {socket.gethostname()} since "
                      f"{time.strftime('%Y-%m-%d %H:%M:%S')}\n".encode(), 0)
        yield path
    finally:
        try:
            path.unlink(missing_ok=True)
        finally:
            os.close(fd)


def prepare(config: DatasetConfig, out) -> Path:
    """Create `out` for `config`, or check that it was started with the same config."""
    out = Path(out)
    if _started_with(config, out) is None:
        write_atomic(out / "meta" / "config.json", json_bytes({"config_hash": config.hash, "config": config.to_json()}))
    return out


def _started_with(config: DatasetConfig, out: Path) -> str | None:
    """The hash `out` was started with `config` under (None: not started): `config.hash`, or the
    recorded hash of a folder that an earlier schema version started with the same settings
    (`started_hash`: a version-1 folder, whatever check backend it recorded); raises
    `ConfigMismatchError` for another config or data without one. Writes nothing."""
    cfg_path = out / "meta" / "config.json"
    if cfg_path.exists():
        try:
            old = json.loads(cfg_path.read_text())
        except ValueError:
            raise ConfigMismatchError(f"{cfg_path} is not valid JSON; delete {out} to start over") from None
        known = started_hash(config, old)
        if known is None:
            recorded = old.get("config") if isinstance(old, dict) else None
            mine = started_record(config, old)  # this config as the folder's schema version writes it
            diffs = diff_configs(recorded if isinstance(recorded, dict) else {}, mine)
            raise ConfigMismatchError(
                f"{out} was started with a different config (hash "
                f"{old.get('config_hash') if isinstance(old, dict) else None}, this run "
                f"{record_hash(mine)}): " + ("; ".join(diffs) or "same keys, different values")
                + f". Resume it with the original settings, use another output folder, or delete {out} "
                "to start over."
            )
        return known
    data = out / "data"
    if data.is_dir() and any(data.iterdir()):
        raise ConfigMismatchError(f"{out} holds data files but no meta/config.json; use an empty folder")
    return None


def _worker_env() -> dict[str, str]:
    one_thread_each()
    return {k: os.environ[k] for k in (*ENV_FOR_WORKERS, *ONE_THREAD) if k in os.environ}


def _run_local(config, todo, out, workers, bar, source=None):
    errors = []
    if workers <= 1:
        for k in todo:
            try:
                build_shard(config, k, out, progress=bar.update, source=source)
            except KeyboardInterrupt:
                raise
            except Exception as exc:  # noqa: BLE001 - reported with the shard number
                errors.append((k, exc))
        return errors
    with workers_pool(workers) as pool:
        futures = {pool.submit(build_shard, config.to_dict(), k, str(out), None, source): k for k in todo}
        for fut in as_completed(futures):
            k = futures[fut]
            try:
                fut.result()
            except Exception as exc:  # noqa: BLE001
                errors.append((k, exc))
            bar.update(len(config.shard_objects(k)))
    return errors


@contextmanager
def _ray_tasks(workers: int, config: DatasetConfig, out):
    """`build_shard` as a Ray task, on the running Ray, else on a local instance (`workers` CPUs) or
    the cluster at `$RAY_ADDRESS` (then `out` must be a folder every node sees, e.g. a shared
    filesystem); a Ray started here is shut down after. Every node is checked first
    (`cluster.check_nodes`: it sees `out` and the library). A task whose node dies is run again
    elsewhere (`max_retries`)."""
    import ray  # the optional `ray` extra, loaded only for --runner ray

    started = False
    if not ray.is_initialized():
        address = os.environ.get("RAY_ADDRESS") or None
        kwargs = {"include_dashboard": False, "runtime_env": {"env_vars": _worker_env()}}
        if address is None:
            kwargs["num_cpus"] = max(1, workers)
        ray.init(address=address, **kwargs)
        started = True
    try:
        nodes = cluster.check_nodes(out, config.ldraw)
        print(cluster.describe(nodes), file=sys.stderr)
        yield ray.remote(num_cpus=1, max_retries=2)(build_shard)
    finally:
        if started:
            ray.shutdown()


def _run_ray(config, todo, out, workers, bar, source=None):
    """The same shard function as Ray tasks (`_ray_tasks`)."""
    import ray

    with _ray_tasks(workers, config, out) as task:
        refs = {task.remote(config.to_dict(), k, str(out), None, source): k for k in todo}
        errors = []
        pending = list(refs)
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            for ref in done:
                k = refs[ref]
                try:
                    ray.get(ref)
                except Exception as exc:  # noqa: BLE001
                    errors.append((k, exc))
                bar.update(len(config.shard_objects(k)))
        return errors


def growers_of(workers: int, growers: int | None = None) -> int:
    """Grower tasks of a lockstep build: `growers` (at most the workers), by default two thirds of
    the workers (on one H200 machine a step's growth took 0.32 s of a process at batch 16, its
    render and encoding 0.20 s of a worker: `docs/results.md`)."""
    return min(max(1, workers), growers or max(1, (2 * workers) // 3))


def _run_grown(config, todo, out, workers, bar, batch: int, runner: str, growers: int | None = None):
    """A lockstep build: `growers` tasks (default two thirds of the workers) grow the objects of the
    missing shards, each the objects of every G-th shard `batch` at a time (`spool.grow`: each
    kept in `spool` as it ends), while the other workers render and encode each shard whose objects
    are all grown, or, when a worker is free, one whose objects are partly grown, rendering each
    object as it is grown (the shard function, `wait=True`): physics and rendering overlap, and
    every grower's checks go to the device. Returns the failed shards as `_run_local` does."""
    workers = max(1, workers)
    growers = growers_of(workers, growers)
    # (An unreadable or foreign spool entry counts as grown here; the shard function grows it.)
    missing = {k: [i for i in config.shard_objects(k) if not spool.has(out, i)] for k in todo}
    # Each grower takes whole shards (every G-th, in order), so a shard's objects end close together.
    parts = [[i for k in todo[g::growers] for i in missing[k]] for g in range(growers)]
    waiting = {k: set(v) for k, v in missing.items()}
    rank = {k: r for r, k in enumerate(todo)}
    errors: list = []
    running: dict = {}
    with ExitStack() as stack:
        if runner == "ray":
            import ray

            task = stack.enter_context(_ray_tasks(workers, config, out))
            grow_task = ray.remote(num_cpus=1, max_retries=2)(spool.grow)
            submit = lambda k: task.remote(config.to_dict(), k, str(out), wait=True)  # noqa: E731
            submit_grow = lambda part: grow_task.remote(config.to_dict(), part, str(out), batch)  # noqa: E731
            finish = ray.get
        else:
            # Growers are submitted first: they hold `growers` of the workers while they run.
            pool = stack.enter_context(workers_pool(workers))
            submit = lambda k: pool.submit(build_shard, config.to_dict(), k, str(out), wait=True)  # noqa: E731
            submit_grow = lambda part: pool.submit(spool.grow, config.to_dict(), part, str(out), batch)  # noqa: E731
            finish = lambda f: f.result()  # noqa: E731
        # While this is there, a shard started before its objects are all grown waits for them.
        stack.enter_context(spool.growers_running(out))
        grow_jobs = [submit_grow(part) for part in parts if part]
        growing = True  # until the spool's mark is removed: a grower failed, or none is left

        def collect(block: bool) -> None:
            for k in [k for k, f in running.items() if block or _done(f)]:
                try:
                    finish(running.pop(k))
                except Exception as exc:  # noqa: BLE001 - reported with the shard number
                    errors.append((k, exc))
                bar.update(len(config.shard_objects(k)))

        while waiting:
            ended = [f for f in grow_jobs if _done(f)]
            grow_jobs = [f for f in grow_jobs if f not in ended]
            failed = False
            for f in ended:
                try:
                    finish(f)
                except Exception as exc:  # noqa: BLE001 - the shards then grow their objects themselves
                    print(f"warning: a grower failed ({type(exc).__name__}: {exc}); its shards grow their "
                          f"own objects", file=sys.stderr)
                    failed = True
            if growing and (failed or not grow_jobs):
                spool.growers_stopped(out)
                growing = False
            collect(False)
            grown = spool.present(out)
            for k in list(waiting):
                waiting[k] -= grown
                if not waiting[k] or not grow_jobs:
                    del waiting[k]
                    running[k] = submit(k)
            # Then, while a worker is free, the shard with the most objects grown, in schedule order:
            # it renders each object as it is grown (`build_shard(..., wait=True)`). In lockstep an
            # object ends only after as many rounds as it has parts, so a shard waiting for all of
            # its objects left the renderers idle while its slowest grew.
            free = workers - len(grow_jobs) - len(running)
            while free > 0:
                started = [k for k in waiting if len(waiting[k]) < len(config.shard_objects(k))]
                if not started:
                    break
                k = min(started, key=lambda k: (len(waiting[k]), rank[k]))
                del waiting[k]
                running[k] = submit(k)
                free -= 1
            if waiting:
                time.sleep(0.2)
        collect(True)
    return errors


def _done(future) -> bool:
    if hasattr(future, "done"):
        return future.done()
    import ray

    return bool(ray.wait([future], timeout=0)[0])


LARGEST_FIRST_MAX = 200_000
"""Objects up to which `largest_first` orders the shards (14 us an object here: about 3 s); past it
the tail it saves is a small share of the build and the shards keep their order."""


def finished_shards(config: DatasetConfig, out) -> set[int]:
    """The shards whose markers say they are done (`read_marker`). The markers folder is listed
    once and only the markers there are read: reading one per shard took minutes, silently, before
    the first shard of `--n 10**8` (25 million shards, almost none done)."""
    folder = marker_path(out, 0).parent
    try:
        names = [e.name for e in os.scandir(folder)]
    except FileNotFoundError:
        return set()
    present = sorted(int(n[:-5]) for n in names if n.endswith(".json") and n[:-5].isdigit())
    identity = folder_identity(config, out)[0]
    return {k for k in present if k < config.num_shards and read_marker(out, k, config, identity) is not None}


def largest_first(config: DatasetConfig, shards: list[int]) -> list[int]:
    """Synthetic shards in decreasing expected work (the sum of their objects' squared target
    lengths: a step's checks grow with the structure), so that the last shards to start are the
    short ones and the workers end together; other sources in order. The data do not depend on it."""
    if config.source != "synthetic" or sum(len(config.shard_objects(k)) for k in shards) > LARGEST_FIRST_MAX:
        return shards
    work = {k: sum(target_steps(config.sampler, i) ** 2 for i in config.shard_objects(k)) for k in shards}
    return sorted(shards, key=lambda k: (-work[k], k))


def _check_source(config: DatasetConfig, source=None) -> None:
    """Raise what the shards would (an unknown part or colour, a missing library: the sampler's
    own checks; a source the builder cannot make) before anything is written. The source is this
    process's (`object_source`), so shards built here reuse it."""
    if config.source == "synthetic" or (config.source == "feedback" and source is None):
        object_source(config)


def build(config: DatasetConfig, out, runner: str = "local", workers: int = 1, progress: bool = True,
          desc: str = "objects", batch: int = 1, growers: int | None = None, source=None,
          mps_mode: str | None = None) -> dict:
    """Build every missing shard of `config` into `out`, then the metadata; returns the summary.

    `runner`: where the shards run, `RUNNERS` ('local': `workers` processes of this machine, or this
    process when 1; 'ray': Ray tasks). `batch` > 1 (synthetic data): objects grown `batch` at a time by `growers` of the workers
    (default two thirds) while the others render (`_run_grown`); the data files are the same
    whatever `batch` and `growers`. `source`: the object source, for a source the builder does not
    make from the config (world feedback, `pipelines.feedback.FeedbackSource`; sent to the worker
    processes or Ray tasks with each shard). The folder is held for the build (`holding`).
    `mps_mode`: with the batched checks ('jax') in several local processes, whether they share each
    GPU through an MPS daemon of the build's own (`factory.mps.shared_gpu`; None: its default).
    `meta/timings.json` records how this run went, the checks' backend among it (not part of the
    config's hash: every backend writes the same files)."""
    if runner not in RUNNERS:
        raise ValueError(f"runner must be one of {RUNNERS}, got {runner!r}")
    if isinstance(batch, bool) or not isinstance(batch, int) or batch < 1:
        raise ValueError(f"batch must be an integer >= 1, got {batch!r}")
    if growers is not None and (isinstance(growers, bool) or not isinstance(growers, int) or growers < 1):
        raise ValueError(f"growers must be an integer >= 1, got {growers!r}")
    t0 = time.perf_counter()
    # A run refused for its config, its parts or its library leaves the folder untouched (so the
    # corrected command is not refused as another config).
    _check_source(config, source)
    _started_with(config, Path(out))
    mps.mode_of(mps_mode)  # a bad value is refused before any work
    cpu0 = usage.cpu_seconds()
    with holding(out), _gpu_sharing(config, runner, workers, batch, growers, mps_mode):
        host = usage.host()
        with usage.GpuWatch(gpus=host["gpus"]) as watch:
            summary = _build(config, out, runner, workers, progress, desc, batch, growers, t0, source)
        cpu1 = usage.cpu_seconds()
        summary["usage"] = {
            "host": host,
            "cpu_seconds": {k: round(cpu1[k] - cpu0[k], 1) for k in cpu0},
            "gpus": watch.report(),
            "gpus_not_sampled": watch.why_not,
        }
        if config.source == "synthetic":
            summary["checks"] = {k: getattr(config.sampler, k) for k in RUN_SETTINGS}
        write_atomic(Path(summary["out"]) / "meta" / "timings.json", json_bytes({
            **({"checks_last_run": summary["checks"]} if "checks" in summary else {}),
            "runner_last_run": runner,
            "wall_seconds_last_run": summary["wall_seconds"],
            "shards_built_last_run": summary["shards_built"],
            "peak_rss_mb_last_run": summary["peak_rss_mb"],
            "usage_last_run": summary["usage"],
            "stage_seconds_all_shards": summary["stage_seconds"],
            "shards_by_node": summary["shards_by_node"],
            "note": "seconds are summed over worker processes; not part of the reproducible output",
        }))
        return summary


def _gpu_sharing(config: DatasetConfig, runner: str, workers: int, batch: int, growers: int | None, mode):
    """MPS for a local build whose worker processes run the batched checks (`factory.mps`): the
    growers of a lockstep build, else every worker; nothing for the reference's checks or Ray."""
    if config.source != "synthetic" or config.sampler.backend != "jax" or runner != "local":
        return contextlib.nullcontext()
    clients = growers_of(workers, growers) if batch > 1 else max(1, workers)
    return mps.shared_gpu(clients, mode)


def _build(config, out, runner, workers, progress, desc, batch, growers, t0, source=None) -> dict:
    out = prepare(config, out)
    remove_stranded(out)
    done = finished_shards(config, out)
    todo = largest_first(config, [k for k in range(config.num_shards) if k not in done])
    done_objects = sum(len(config.shard_objects(k)) for k in done)
    with tqdm(total=config.n_objects, initial=done_objects, desc=desc, unit="obj", disable=not progress,
              file=sys.stderr, dynamic_ncols=True) as bar:
        if batch > 1 and config.source == "synthetic":
            errors = _run_grown(config, todo, out, workers, bar, batch, runner, growers) if todo else []
        else:
            run = _run_local if runner == "local" else _run_ray
            errors = run(config, todo, out, workers, bar, source) if todo else []
    if errors:
        k, exc = errors[0]
        if all(isinstance(e, LDrawError) for _, e in errors):
            raise ShardInputError(f"{len(errors)} shard(s) failed on their input (first: shard {k}: {exc}); "
                                  "finished shards are kept; fix the input and re-run")
        raise ShardFailedError(f"{len(errors)} shard(s) failed (first: shard {k}: {type(exc).__name__}: {exc}); "
                               "finished shards are kept, re-run the same command to retry the rest")
    summary = finalize(config, out)
    summary["wall_seconds"] = round(time.perf_counter() - t0, 3)
    summary["shards_built"] = len(todo)
    summary["shards_skipped"] = config.num_shards - len(todo)
    summary["peak_rss_mb"] = usage.peak_rss_mb()
    return summary  # `build` adds what the run used and writes meta/timings.json


# -- metadata ----------------------------------------------------------------------------------------
def _versions() -> dict:
    out = {}
    for name in PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    out["python"] = ".".join(map(str, sys.version_info[:3]))
    return out


def finalize(config: DatasetConfig, out) -> dict:
    """`meta/info.json`, `meta/objects.jsonl`, `README.md` and `gallery/` from the markers. The
    config record and hash in info.json are those the folder knows the config by
    (`folder_identity`: a folder an earlier schema version started keeps its own)."""
    out = Path(out)
    identity, record = folder_identity(config, out)
    markers = [read_marker(out, k, config, identity) for k in range(config.num_shards)]
    if any(m is None for m in markers):
        raise ShardFailedError("not every shard is complete; re-run the build")
    counts = {s: {"objects": 0, "steps": 0, "bytes": 0} for s in SPLITS}
    stats: dict[str, dict[str, int]] = {}
    stages: dict[str, float] = {}
    objects = []
    built_on: dict[str, int] = {}
    for m in markers:
        where = m.get("node") or m.get("host") or "?"
        built_on[where] = built_on.get(where, 0) + 1
        for s in SPLITS:
            counts[s]["objects"] += m["counts"][s]["objects"]
            counts[s]["steps"] += m["counts"][s]["steps"]
            counts[s]["bytes"] += m["bytes"][s]
        for g, c in m["stats"].items():
            agg = stats.setdefault(g, {})
            for r, n in c.items():
                agg[r] = agg.get(r, 0) + n
        for k, v in m["seconds"].items():
            stages[k] = stages.get(k, 0.0) + v
        objects += m["objects"]
    total = {k: sum(counts[s][k] for s in SPLITS) for k in ("objects", "steps", "bytes")}
    statistics = {g: dict(sorted(c.items())) for g, c in sorted(stats.items())}
    typed = DatasetInfo(
        dataset_id=config.dataset_id,
        source=config.source,
        config=record,
        counts={s: Counts(**c) for s, c in counts.items()},
        total=Counts(**total),
        splits_present=tuple(s for s in SPLITS if counts[s]["steps"] > 0),
        schema_version=record["schema_version"],
        seed=config.seed,
        config_hash=identity,
        num_shards=config.num_shards,
        statistics=statistics,
        package_versions=_versions(),
        **(_feedback_info(config, statistics) if config.source == "feedback" else {}),
    )
    write_info(out, typed)
    info = typed.to_dict()
    meta = out / "meta"
    write_atomic(meta / "objects.jsonl",
                 "".join(json.dumps(o, sort_keys=True) + "\n" for o in objects).encode())
    write_gallery(config, out, info)
    write_atomic(out / "README.md", dataset_card(config, info).encode())
    return {
        "dataset_id": config.dataset_id,
        "source": config.source,
        "out": str(out),
        "counts": counts,
        "total": total,
        "statistics": info["statistics"],
        "stage_seconds": {k: round(v, 1) for k, v in sorted(stages.items())},
        "shards_by_node": dict(sorted(built_on.items())),
    }


def _feedback_info(config: DatasetConfig, statistics: dict) -> dict:
    """A feedback dataset's `DatasetInfo` fields beyond the builder's: pose only, the `feedback`
    image column, and where the rows came from (the keys feedback folders have always had)."""
    spec = config.feedback
    return {
        "tasks": ("pose",),
        "extra_images": FEEDBACK_IMAGES,
        "details": {
            "source_dataset": spec.dataset,
            "source_dataset_id": spec.dataset_id,
            "source_config_hash": spec.config_hash,
            "source_split": spec.split,
            "predictions": spec.predictions,
            "predictions_sha256": spec.predictions_sha256,
            "reasons": statistics.get("feedback", {}),
        },
    }


def summary_line(summary: dict) -> str:
    """The one-line report of a build."""
    c, t = summary["counts"], summary["total"]
    stats = summary["statistics"]
    if "rejections" in stats:
        label, reasons = "rejected candidates", stats["rejections"]
    elif "feedback" in stats:
        label, reasons = "pose answers", stats["feedback"]
    else:
        label, reasons = "physics flags", stats.get("physics_flags", {})
    why = ", ".join(f"{k} {v}" for k, v in sorted(reasons.items(), key=lambda kv: (-kv[1], kv[0]))) or "none"
    stages = ", ".join(f"{k} {v:.0f}" for k, v in summary["stage_seconds"].items())
    resumed = f", {summary['shards_skipped']} shard(s) already done" if summary.get("shards_skipped") else ""
    nodes = summary.get("shards_by_node", {})
    if len(nodes) > 1:  # a cluster's build: the shards each node wrote (Ray node ids, or hosts)
        resumed += "; shards by node: " + ", ".join(f"{k[:12]} {v}" for k, v in nodes.items())
    return (f"{summary['dataset_id']}: {t['objects']} objects ({c['train']['objects']} train, "
            f"{c['test']['objects']} test), {t['steps']} steps ({c['train']['steps']} train, "
            f"{c['test']['steps']} test); {label}: {why}; wall {summary['wall_seconds']:.1f} s"
            f"{resumed}; stage s (summed over workers): {stages}; {t['bytes'] / 1e6:.1f} MB in {summary['out']}"
            + (f"; peak RSS {summary['peak_rss_mb']['main']:.0f} MB main, "
               f"{summary['peak_rss_mb']['largest_worker']:.0f} MB largest worker" if "peak_rss_mb" in summary else "")
            + (f"; {usage.describe(summary['usage'])}" if "usage" in summary else ""))

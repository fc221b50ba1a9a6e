"""The nodes of a Ray cluster a build runs on: a check, before any shard, that every node can build
(it sees the output folder and can write to it, and reads the LDraw library), and the name of the
node a shard was built on (kept in its completion marker, summed in the build's summary).

Shards are Ray tasks with retries (`build._ray_tasks`): a node that dies mid-build loses the shards
it was writing (their temporary files are removed when the shard runs again) and Ray runs them
again on the nodes left; every shard is written atomically, so the data are the same bytes.
"""

from __future__ import annotations

import os
import secrets
import socket
import sys
from pathlib import Path

CHECK_SECONDS = 300.0
"""How long every node has to answer the check before the build stops naming those that did not
(a node that is alive but cannot start a worker would otherwise hold the build forever). Starting
a node's first worker took more than 60 s on a 2-core machine running other work beside a
three-node test cluster."""


class ClusterError(RuntimeError):
    """A node of the cluster cannot take part in a build (named, with what it lacks)."""


def node_id() -> str | None:
    """The Ray node this process runs on, or None outside a Ray worker (Ray is not imported here)."""
    ray = sys.modules.get("ray")
    if ray is None or not ray.is_initialized():
        return None
    try:
        return ray.get_runtime_context().get_node_id()
    except Exception:  # noqa: BLE001 - only a label for the marker
        return None


def where() -> dict:
    """What a shard's marker records of the process that built it."""
    node = node_id()
    return {"host": socket.gethostname(), "pid": os.getpid(), **({"node": node} if node else {})}


def node_label(node: str, ip: str | None = None, host: str | None = None) -> str:
    parts = [p for p in (host, ip) if p]
    return f"node {node[:12]}" + (f" ({', '.join(parts)})" if parts else "")


def probe(token_path: str, token: str, library: str | None) -> dict:
    """Run on one node: what it lacks for a build (empty when nothing)."""
    problems = []
    path = Path(token_path)
    out = path.parent.parent
    try:
        seen = path.read_text() == token
    except OSError:
        seen = False
    if not seen:
        problems.append(f"does not see the output folder {out} as the driver does (it must be one folder "
                        "every node shares, e.g. on a network filesystem)")
    else:
        test = path.with_name(f"{path.name}.{socket.gethostname()}.{os.getpid()}.tmp")
        try:
            test.write_bytes(b"")
            test.unlink()
        except OSError as exc:
            problems.append(f"cannot write in the output folder {out} ({exc.strerror or exc})")
    if library is not None and not os.access(library, os.R_OK):
        problems.append(f"has no readable LDraw library at {library} (the library must be at the same path "
                        "on every node)")
    return {"host": socket.gethostname(), "problems": problems}


def check_nodes(out, library: str | None, timeout: float = CHECK_SECONDS) -> list[dict]:
    """Ask every alive node with CPUs whether it can build into `out` with `library` (one small
    task pinned to each); raise `ClusterError` naming each node that cannot, or that did not
    answer within `timeout` seconds. Returns the nodes: id, address, host and CPUs."""
    import ray
    from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

    nodes = [n for n in ray.nodes() if n.get("Alive") and n.get("Resources", {}).get("CPU", 0) > 0]
    if not nodes:
        raise ClusterError("the Ray cluster has no alive node with CPUs to run shards on")
    meta = Path(out) / "meta"
    meta.mkdir(parents=True, exist_ok=True)
    token = secrets.token_hex(16)
    token_path = meta / f".node-check-{token[:8]}"
    token_path.write_text(token)
    task = ray.remote(num_cpus=0, max_retries=0)(probe)
    try:
        refs = {task.options(scheduling_strategy=NodeAffinitySchedulingStrategy(n["NodeID"], soft=False))
                .remote(str(token_path), token, library): n for n in nodes}
        ready, pending = ray.wait(list(refs), num_returns=len(refs), timeout=timeout)
        problems, found = [], []
        for ref in ready:
            n = refs[ref]
            try:
                answer = ray.get(ref)
            except Exception as exc:  # noqa: BLE001 - a node that cannot run our code at all
                problems.append(f"{node_label(n['NodeID'], n.get('NodeManagerAddress'))}: could not run the "
                                f"check ({type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''})")
                continue
            label = node_label(n["NodeID"], n.get("NodeManagerAddress"), answer["host"])
            problems += [f"{label} {p}" for p in answer["problems"]]
            found.append({"node": n["NodeID"], "address": n.get("NodeManagerAddress"), "host": answer["host"],
                          "cpus": n["Resources"].get("CPU", 0)})
        for ref in pending:
            n = refs[ref]
            problems.append(f"{node_label(n['NodeID'], n.get('NodeManagerAddress'))}: no answer within "
                            f"{timeout:.0f} s (is its worker able to start?)")
            ray.cancel(ref, force=True)
    finally:
        token_path.unlink(missing_ok=True)
    if problems:
        raise ClusterError("nodes of the Ray cluster cannot build this dataset; nothing was built:\n  "
                           + "\n  ".join(problems))
    return sorted(found, key=lambda n: n["node"])


def describe(nodes: list[dict]) -> str:
    cpus = sum(n["cpus"] for n in nodes)
    return f"ray: {len(nodes)} node(s), {cpus:g} CPUs (" + ", ".join(
        f"{n['host']} {n['address']} {n['cpus']:g}" for n in nodes) + ")"

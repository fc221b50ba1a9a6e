"""`settle` batched on a GPU: many predicted placements, of any scenes, released at once in
MuJoCo Warp (the GPU implementation of MuJoCo that MJX ships, `mujoco.mjx.third_party.mujoco_warp`).

`settle_many(cases)` gives, per case (structure, part, pose, floor_y), what `settle.settle` gives.
Everything but the simulation is the reference's own code (`settle.Release`): the overlap check
and snapping before simulating, then after every `snap_every` steps, on the host, snapping along
the part's path (its pose after each step, kept on the device by a small kernel; the checks judge
each candidate once per scene: the judge is shared) and the at-rest window, and at the
end the outcome from the end pose and the contacts MuJoCo C finds there (`mj_forward` on the scene's
own `MjModel`, `settle.settle_model`).

One world per case at a time, one model per batch. Feedback data is one wrong prediction per
scene (a structure at some step and the part predicted next), so worlds cannot share a model as
robot simulations do. A world whose part has stopped (snapped, at rest, out of time) takes the
next case of the batch: its state is cleared (`reset_data` of that world alone) and the case's
rows are copied into the world's rows of the batched fields, so each world runs about as many
steps as its cases need, not as many as the batch's slowest case (MuJoCo C stops each part once
it is at rest: 189 steps on average on `pipelines.bench_settle --seed 1`, against 1,000 for a
part still moving at the end). A batch's model is a template of slots: the floor, `S` mesh geoms of a static body
(the structure's collision pieces) and `P` mesh geoms of the free part, every geom pointing at a
pool holding the meshes of all the batch's scenes. Per world (MuJoCo Warp's batched model fields)
each slot gets its scene's mesh (`geom_dataid`), placement, bounds, and the part its mass and
inertia; the slots a scene does not fill hold a tiny mesh far below the floor (structure) or at the
part's origin with a contact margin of -1 m (part), so they never make a contact. Each world is
shifted so that its floor is at the template's (z = 0). `S` and `P` are rounded up to a power of two
(`STRUCTURE_SLOTS`, `PART_SLOTS`): Warp compiles its kernels once per machine (its kernel cache), a
process loads them once, and a batch's model only changes the arrays they read. The geoms of
a static body are placed once, when the data is made (Warp does not move them again), so their
world poses are written into the data's `geom_xpos`/`geom_xmat` directly.

MuJoCo Warp computes in float32 (MuJoCo C in float64) and its convex collision (GJK/EPA with
multi-contact) is not MuJoCo C's, so trajectories differ slightly; how often the outcomes agree
is what `pipelines.bench_settle` measures. On a machine without a GPU Warp runs its kernels on the
CPU (slowly: the tests use it); with CUDA each chunk of `snap_every` steps is one captured graph.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from functools import cache

import mujoco
import numpy as np

from factory import gpus
from factory.physics.collide import _fmt, _template
from factory.physics.settle import (Release, Scenes, SettleConfig, SettleScene, Settled, _pose_of, _touched,
                                    settle_all, still)
from factory.physics.settle import _simulate as _simulate_c
from factory.pose import LDU_M, Pose, points_to_mujoco, poses_from_mujoco

PART_SLOTS = (4, 8, 16, 32, 64, 128)
"""Mesh geoms of the free part per batch: the least of these that holds the batch's largest part."""
STRUCTURE_SLOTS = tuple(2 ** k for k in range(4, 15))
"""Mesh geoms of the structure per batch: the least of these that holds its largest structure."""
CONTACTS_PER_WORLD = 160
"""Contacts kept per world (MuJoCo Warp allocates them up front); more are dropped and counted."""
CONSTRAINTS_PER_WORLD = 6 * CONTACTS_PER_WORLD
"""Constraint rows kept per world (three per contact of an elliptic cone with condim 3). The
contacts are pooled over the batch, so one world may take more than `CONTACTS_PER_WORLD`; at 3 per
contact (480 rows) one world of 500 predictions ran out of rows and its state stopped being
finite (settled again on MuJoCo C: `MjxStats.diverged`)."""
BATCH = 4096
"""Worlds per batch at most."""
REFILLS = 4
"""Cases per batch, at most, per world: a world whose part has stopped takes the next case."""

_PARK = "-1e-4 -1e-4 -1e-4 1e-4 -1e-4 -1e-4 0 1e-4 -1e-4 0 0 1e-4"  # a 0.2 mm tetrahedron
_PART_INERTIAL = '<inertial pos="1e-3 2e-3 3e-3" quat="0.9 0.1 0.2 0.3" mass="0.001" diaginertia="1e-9 2e-9 3e-9"/>'
"""The template part's inertia, replaced per world (`_BATCHED`). Off the body's origin and turned:
MuJoCo marks a body whose inertia sits at its origin, along its axes, as one whose centre of mass
is its origin (`body_sameframe`, `body_simple`), and MuJoCo Warp then takes the shortcuts that
allows in every world whatever its batched `body_ipos`: a part whose centre of mass is off its
origin turned and drifted in free fall (a 3665 dropped 20 LDU turned 13 degrees in 30 ms)."""
_BATCHED = ("geom_dataid", "geom_pos", "geom_quat", "geom_aabb", "geom_rbound", "geom_size", "geom_margin",
            "body_mass", "body_inertia", "body_ipos", "body_iquat", "body_invweight0", "body_subtreemass",
            "dof_invweight0")


@dataclass
class MjxStats:
    """What `settle_many` did (filled in when passed)."""

    device: str = ""
    """The Warp device the batches ran on."""
    batches: int = 0
    """Batches simulated (one model each)."""
    simulated: int = 0
    """Cases simulated (the others were decided before simulating or fell back)."""
    fallbacks: int = 0
    """Cases run on MuJoCo C because MuJoCo Warp refused their scene or diverged on it."""
    diverged: int = 0
    """Of those, cases whose Warp state stopped being finite (run again on MuJoCo C)."""
    first_chunk_s: float = 0.0
    """Seconds of each batch's first chunk (compiling Warp's kernels, the first time in a process)."""
    run_s: float = 0.0
    """Seconds of the other chunks, the host's rules included."""
    step_s: float = 0.0
    """Of all chunks' seconds, those of the device: launching the steps and waiting for them."""
    rules_s: float = 0.0
    """Of all chunks' seconds, those of the host's rules (snapping sweeps, the at-rest window)."""
    prepare_s: float = 0.0
    """Seconds building batches: the scenes' models, the template, putting them on the device."""
    contacts_dropped: int = 0
    """Chunks after which a batch had used all its contacts (`CONTACTS_PER_WORLD` per world)."""
    refused: list[str] = field(default_factory=list)
    """Why MuJoCo Warp refused each scene it refused."""


@cache
def _warp():
    """(warp, mujoco_warp), imported once and quiet. Warp keeps its compiled kernels in its own
    per-user cache (`WARP_CACHE_PATH`, else ~/.cache/warp): they depend on Warp's version and the
    device, not on anything of the factory's."""
    import warp as wp  # optional: the [warp] extra
    from mujoco.mjx.third_party import mujoco_warp as mjw

    wp.config.quiet = True
    wp.init()
    return wp, mjw


@cache
def _kernels():
    """The batch's own Warp kernels, beside MuJoCo Warp's step (`_simulate`):

    - `keep`: each world's pose of one body after a step, into row `k` of a path history (the
      snapping test follows the path step by step: `settle.Release.sweep`);
    - `roll`: row `src` of the history (the pose after the last chunk) into row 0, where the next
      chunk's path starts, and each world's `flag` cleared;
    - `near`: per world, whether a snapping candidate of its case (`first`, `count`: its stretch
      of `target`) lies within the case's `reach` of the path through rows 0..k (straight between
      them): the test of `SnapTargets.along`, for every world at once. It only spares the host the worlds
      that cannot snap in this chunk (`flag` 0); the host sweeps each flagged world's path with
      the reference's own test. `reach` carries a margin for float32."""
    wp, _ = _warp()

    @wp.kernel
    def keep(xpos: wp.array2d(dtype=wp.vec3), xmat: wp.array2d(dtype=wp.mat33), body: int, k: int,
             pos: wp.array2d(dtype=wp.vec3), mat: wp.array2d(dtype=wp.mat33)):
        w = wp.tid()
        pos[k, w] = xpos[w, body]
        mat[k, w] = xmat[w, body]

    @wp.kernel
    def roll(pos: wp.array2d(dtype=wp.vec3), mat: wp.array2d(dtype=wp.mat33), src: int, flag: wp.array(dtype=wp.int32)):
        w = wp.tid()
        pos[0, w] = pos[src, w]
        mat[0, w] = mat[src, w]
        flag[w] = 0

    @wp.kernel
    def near(pos: wp.array2d(dtype=wp.vec3), k: int, world_case: wp.array(dtype=wp.int32), first: wp.array(dtype=wp.int32),
             count: wp.array(dtype=wp.int32), target: wp.array(dtype=wp.vec3), reach: wp.array(dtype=wp.float32),
             flag: wp.array(dtype=wp.int32)):
        w = wp.tid()
        i = world_case[w]
        if i < 0:
            return
        for p in range(first[i], first[i] + count[i]):
            c = target[p]
            for j in range(k):
                a = pos[j, w]
                ab = pos[j + 1, w] - a
                f = wp.clamp(wp.dot(c - a, ab) / wp.max(wp.dot(ab, ab), 1.0e-20), 0.0, 1.0)
                if wp.length(c - (a + f * ab)) <= reach[i]:
                    flag[w] = 1

    return keep, roll, near


def default_device() -> str:
    """A GPU when Warp sees one (worker k of a pool: GPU k mod G, as `factory.gpus` spreads the
    checks), else 'cpu'."""
    wp, _ = _warp()
    if wp.get_cuda_device_count() == 0:
        return "cpu"
    k = gpus.slot()
    return f"cuda:{k % wp.get_cuda_device_count() if k is not None else 0}"


def _bucket(n: int, sizes: tuple[int, ...]) -> int:
    for b in sizes:
        if b >= n:
            return b
    raise ValueError(f"{n} geoms is more than the largest slot count {sizes[-1]}")


@dataclass
class _SceneSlots:
    """A scene's geoms as the template's slots take them (floor-shifted, LDraw-independent)."""

    scene: SettleScene
    floor: np.ndarray  # the floor geom's position (the world's shift)
    structure: list[tuple]  # (mesh name, world pos, quat, aabb, rbound, size)
    part: list[tuple]  # (mesh name, body pos, quat, aabb, rbound, size)
    body: dict  # the part body's inertial fields and the dofs' invweight0


def _slots(scene: SettleScene) -> _SceneSlots:
    m = scene.model
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    floor = m.geom_pos[scene.floor_geom].copy()
    structure, part = [], []
    for g in range(m.ngeom):
        if scene.owner[g] == -2:
            continue
        name = m.mesh(int(m.geom_dataid[g])).name
        bounds = (m.geom_aabb[g].reshape(2, 3).copy(), float(m.geom_rbound[g]), m.geom_size[g].copy())
        if scene.owner[g] >= 0:
            q = np.zeros(4)
            mujoco.mju_mat2Quat(q, d.geom_xmat[g])
            structure.append((name, d.geom_xpos[g] - floor, q) + bounds)
        else:
            part.append((name, m.geom_pos[g].copy(), m.geom_quat[g].copy()) + bounds)
    b = scene.part_body
    body = {k: getattr(m, k)[b].copy() for k in ("body_mass", "body_inertia", "body_ipos", "body_iquat",
                                                   "body_invweight0", "body_subtreemass")}
    body["dof_invweight0"] = m.dof_invweight0.copy()
    return _SceneSlots(scene, floor, structure, part, body)


def _template_model(pool: dict[str, str], n_structure: int, n_part: int, config: SettleConfig) -> mujoco.MjModel:
    assets = "".join(f'<mesh name="{n}" vertex="{v}"/>' for n, v in pool.items()) + f'<mesh name="park" vertex="{_PARK}"/>'
    structure = ('<body name="structure"><inertial pos="0 0 0" mass="1" diaginertia="1 1 1"/>'
                 + '<geom mesh="park" pos="0 0 -100"/>' * n_structure + "</body>")
    xml = _template("settle.xml").format(
        timestep=f"{config.timestep:.7g}", condim=3, friction=f"{config.friction:.7g} 0.005 0.0001",
        solref=_fmt(config.solref), solimp=_fmt(config.solimp), assets=assets, floor_z="0", structure=structure,
        pos="0 0 1", quat="1 0 0 0", inertial=_PART_INERTIAL,
        part='<geom mesh="park"/>' * n_part)
    return mujoco.MjModel.from_xml_string(xml)


def settle_many(cases, config: SettleConfig = SettleConfig(), device: str | None = None,
                stats: MjxStats | None = None, batch: int = BATCH) -> list[Settled]:
    """`settle` of every case (structure, part, pose, floor_y; floor_y None for the structure's
    lowest point), the simulations batched in MuJoCo Warp on `device` ('cpu', 'cuda:0'; the GPU
    when there is one) over at most `batch` worlds at once, a world taking the next case when its
    part stops. Results in the cases' order."""
    stats = stats if stats is not None else MjxStats()
    out: list[Settled | None] = [None] * len(cases)
    scenes = Scenes(config)
    pending: list[tuple[int, tuple, Release]] = []
    t0 = time.perf_counter()
    for i, case in enumerate(cases):
        key, release = scenes.release(*case)
        if release.result is not None:
            out[i] = release.result
        else:
            pending.append((i, key, release))
    slots: dict[tuple, _SceneSlots] = {}
    for _, key, release in pending:
        if key not in slots:
            slots[key] = _slots(scenes.model(key, release))
    stats.prepare_s += time.perf_counter() - t0
    if not pending:
        return out  # type: ignore[return-value]
    device = device or default_device()
    stats.device = device
    # A run of `REFILLS * batch` cases shares one model and its worlds (the cases' rows are kept on
    # the device: memory grows with the run, so a longer list is cut into runs).
    group = REFILLS * batch
    for start in range(0, len(pending), group):
        chunk = pending[start:start + group]
        try:
            ends = _simulate([slots[k] for _, k, _ in chunk], [r for _, _, r in chunk], config, device, stats, batch)
        except NotImplementedError as e:  # a model MuJoCo Warp cannot run: the reference runs it
            stats.refused.append(str(e))
            stats.fallbacks += len(chunk)
            ends = settle_all([(r.structure, r.part, r.pose, r.floor_y) for _, _, r in chunk], config)
        for (i, _, _), settled in zip(chunk, ends):
            out[i] = settled
    return out  # type: ignore[return-value]


def _simulate(slots: list[_SceneSlots], releases: list[Release], config: SettleConfig, device: str,
              stats: MjxStats, worlds: int) -> list[Settled]:
    """Undecided releases (case i: `slots[i]`, `releases[i]`) simulated in MuJoCo Warp on at most
    `worlds` worlds, a world taking the next case when its part stops, the host's rules after
    every chunk."""
    wp, mjw = _warp()
    t0 = time.perf_counter()
    n = len(releases)
    pool: dict[str, str] = {}
    for s in {id(s): s for s in slots}.values():
        for name, verts in s.scene.meshes.items():
            pool.setdefault(name, verts)
    n_structure = _bucket(max(len(s.structure) for s in slots), STRUCTURE_SLOTS)
    n_part = _bucket(max(len(s.part) for s in slots), PART_SLOTS)
    tm = _template_model(pool, n_structure, n_part, config)
    mesh_id = {tm.mesh(i).name: i for i in range(tm.nmesh)}
    body_part = mujoco.mj_name2id(tm, mujoco.mjtObj.mjOBJ_BODY, "part")
    body_structure = mujoco.mj_name2id(tm, mujoco.mjtObj.mjOBJ_BODY, "structure")
    s_slots = np.flatnonzero(tm.geom_bodyid == body_structure)
    p_slots = np.flatnonzero(tm.geom_bodyid == body_part)
    arr = {k: np.repeat(np.asarray(getattr(tm, k))[None], n, 0) for k in _BATCHED}
    arr["geom_aabb"] = arr["geom_aabb"].reshape(n, tm.ngeom, 2, 3)
    arr["geom_margin"][:, p_slots] = -1.0
    xmat = np.repeat(np.eye(3)[None, None], n, 0).repeat(tm.ngeom, 1)
    xpos = np.zeros((n, tm.ngeom, 3))
    xpos[:, s_slots] = (0.0, 0.0, -100.0)
    qpos = np.zeros((n, 7))
    for w, (s, r) in enumerate(zip(slots, releases)):
        for geoms, ids in ((s.structure, s_slots), (s.part, p_slots)):
            for slot, (name, pos, quat, aabb, rbound, size) in zip(ids, geoms):
                arr["geom_dataid"][w, slot] = mesh_id[name]
                arr["geom_pos"][w, slot], arr["geom_quat"][w, slot] = pos, quat
                arr["geom_aabb"][w, slot], arr["geom_rbound"][w, slot], arr["geom_size"][w, slot] = aabb, rbound, size
                arr["geom_margin"][w, slot] = 0.0
        for slot, (_, pos, quat, *_rest) in zip(s_slots, s.structure):
            xpos[w, slot] = pos
            mat = np.zeros(9)
            mujoco.mju_quat2Mat(mat, quat)
            xmat[w, slot] = mat.reshape(3, 3)
        for k in ("body_mass", "body_inertia", "body_ipos", "body_iquat", "body_invweight0", "body_subtreemass"):
            arr[k][w, body_part] = s.body[k]
        arr["dof_invweight0"][w] = s.body["dof_invweight0"]
        pos, quat = r.pose.to_mujoco_quat()
        qpos[w, :3], qpos[w, 3:] = pos - s.floor, quat
    shift = np.array([s.floor for s in slots])
    steps = int(round(config.seconds / config.timestep))
    # Worlds are refilled: one whose part has stopped takes the next case, so that each runs about
    # its own settling time, not the slowest case's. That needs every chunk to be whole (a case
    # then ends on a chunk's end whenever it starts); otherwise every case gets a world at once.
    refill = steps % config.snap_every == 0
    W = min(n, worlds) if refill else n
    with wp.ScopedDevice(device):
        mw = mjw.put_model(tm, batch_sizes={k: W for k in _BATCHED})
        naconmax = W * CONTACTS_PER_WORLD
        dw = mjw.make_data(tm, nworld=W, naconmax=naconmax, njmax=CONSTRAINTS_PER_WORLD)
        # Every case's rows on the device, copied into a world's rows when it takes the case.
        stage, rows_of = {}, {}
        for k, v in [*arr.items(), ("geom_xpos", xpos), ("geom_xmat", xmat), ("qpos", qpos)]:
            a = getattr(mw, k) if k in arr else getattr(dw, k)
            stage[k] = wp.array(v.astype(np.int32 if a.dtype == wp.int32 else np.float32), dtype=a.dtype)
            rows_of[k] = a
        keep, roll, near = _kernels()
        # Row `snap_every` of the path history holds the pose a chunk starts from (rolled into row
        # 0 as the chunk begins; rows 1..k: after each of its k steps): at first, the released pose.
        hist_pos = wp.zeros((config.snap_every + 1, W), dtype=wp.vec3)
        hist_mat = wp.zeros((config.snap_every + 1, W), dtype=wp.mat33)
        start_pos = wp.array(qpos[:, :3].astype(np.float32), dtype=wp.vec3)
        start_mat = wp.array(np.array([r.pose.to_mujoco()[1] for r in releases], np.float32), dtype=wp.mat33)
        # Each case's snapping candidates (translations in its world's frame: metres, floor at
        # z = 0) as one stretch of `target`, and its reach (`SnapTargets.reach`).
        first, count, targets = np.zeros(n, np.int32), np.zeros(n, np.int32), [np.zeros((0, 3))]
        reach = np.zeros(n, np.float32)
        for i, (s, r) in enumerate(zip(slots, releases)):
            found = r.judge.targets
            first[i] = sum(len(x) for x in targets)
            if len(found.owner):
                targets.append(points_to_mujoco(found.t) - s.floor)
                count[i] = len(found.t)
            reach[i] = (found.reach(config.snap) + 1e-3) * LDU_M  # 1e-3 LDU: float32's error, and more
        first_d, count_d = wp.array(first, dtype=wp.int32), wp.array(count, dtype=wp.int32)
        target_d = wp.array(np.concatenate(targets).astype(np.float32).reshape(-1, 3), dtype=wp.vec3)
        reach_d = wp.array(reach, dtype=wp.float32)
        case_d = wp.zeros(W, dtype=wp.int32)
        flag = wp.zeros(W, dtype=wp.int32)
        mask = wp.zeros(W, dtype=wp.bool)
        case_of = np.full(W, -1, np.int64)  # each world's case, -1 when none is left for it

        def take(ws: np.ndarray, cases: np.ndarray) -> None:
            """Worlds `ws` take cases `cases`: their state cleared, the cases' rows copied in."""
            m = np.zeros(W, bool)
            m[ws] = True
            mask.assign(m)
            mjw.reset_data(mw, dw, reset=mask)
            # One copy per field for each run of worlds taking consecutive cases (at the start,
            # all of them), not one per world.
            cut = np.flatnonzero((np.diff(ws) != 1) | (np.diff(cases) != 1)) + 1
            for run_w, run_i in zip(np.split(ws, cut), np.split(cases, cut)):
                w, i, m = int(run_w[0]), int(run_i[0]), len(run_w)
                for k, a in rows_of.items():
                    row = a.size // a.shape[0]
                    wp.copy(a, stage[k], dest_offset=w * row, src_offset=i * row, count=m * row)
                wp.copy(hist_pos, start_pos, dest_offset=config.snap_every * W + w, src_offset=i, count=m)
                wp.copy(hist_mat, start_mat, dest_offset=config.snap_every * W + w, src_offset=i, count=m)
            case_of[ws] = cases
            case_d.assign(case_of.astype(np.int32))

        take(np.arange(W), np.arange(W))
        stats.prepare_s += time.perf_counter() - t0
        stats.batches += 1
        stats.simulated += n

        def chunk(k: int) -> None:
            wp.launch(roll, dim=W, inputs=[hist_pos, hist_mat, config.snap_every, flag])
            for j in range(k):
                mjw.step(mw, dw)
                wp.launch(keep, dim=W, inputs=[dw.xpos, dw.xmat, body_part, j + 1, hist_pos, hist_mat])
            wp.launch(near, dim=W, inputs=[hist_pos, k, case_d, first_d, count_d, target_d, reach_d, flag])

        window = releases[0].window
        chunks = -(-steps // config.snap_every)
        # Each world's pose after every chunk of its case (LDraw), the released pose first: the
        # at-rest window.
        R_after = np.zeros((W, chunks + 1, 3, 3))
        t_after = np.zeros((W, chunks + 1, 3))
        R_after[:, 0] = [r.pose.R for r in releases[:W]]
        t_after[:, 0] = [r.pose.t for r in releases[:W]]
        com = np.array([r.com for r in releases])
        c_of = np.zeros(W, np.int64)  # chunks its case has run
        queue = W  # the next case to take a world
        active = np.arange(W)
        diverged: set[int] = set()
        end_qpos = np.zeros((n, 7))
        stopped = np.zeros(n, np.int64)
        graph, launched = None, 0
        while len(active):
            k = min(config.snap_every, steps - int(c_of[active].min()) * config.snap_every)
            t1 = time.perf_counter()
            if graph is None and k == config.snap_every and wp.get_device(device).is_cuda and launched:
                with wp.ScopedCapture() as capture:
                    chunk(k)
                graph = capture.graph
            if graph is not None and k == config.snap_every:
                wp.capture_launch(graph)
            else:
                chunk(k)
            launched += 1
            q, flagged = dw.qpos.numpy(), flag.numpy()
            path_pos, path_mat = hist_pos.numpy()[:k + 1], hist_mat.numpy()[:k + 1]
            if int(dw.nacon.numpy()[0]) >= naconmax:
                stats.contacts_dropped += 1
            t2 = time.perf_counter()
            c_of[active] += 1
            done = np.minimum(c_of * config.snap_every, steps)
            cases = case_of[active]
            end_qpos[cases], stopped[cases] = q[active], done[active]
            finite = np.isfinite(q[active]).all(axis=1)
            diverged.update(int(i) for i in cases[~finite])  # left to the reference below
            ended = list(active[~finite])
            active = active[finite]
            c = c_of[active]
            R_after[active, c], t_after[active, c] = poses_from_mujoco(path_pos[k, active] + shift[case_of[active]],
                                                                       path_mat[k, active])
            snapped = np.zeros(len(active), bool)
            for j in np.flatnonzero(flagged[active]):
                w, i = active[j], case_of[active[j]]
                R_path, t_path = poses_from_mujoco(path_pos[1:, w] + shift[i], path_mat[1:, w])
                path = [Pose(r, x) for r, x in zip(R_path, t_path)]
                snapped[j] = releases[i].sweep(Pose(R_after[w, c[j] - 1], t_after[w, c[j] - 1]), path, int(done[w]))
            ended += list(active[snapped])
            active = active[~snapped]
            # The window: the poses after the last `window` chunks of the case and the one before.
            full = active[c_of[active] >= window]
            if len(full):
                span = c_of[full][:, None] - window + np.arange(window + 1)
                rest = still(R_after[full[:, None], span], t_after[full[:, None], span], com[case_of[full]], config)
                for i in case_of[full[rest]]:
                    releases[i].at_rest = True
                ended += list(full[rest])
                active = np.setdiff1d(active, full[rest])
            out_of_time = active[done[active] >= steps]
            ended += list(out_of_time)
            active = np.setdiff1d(active, out_of_time)
            if ended and queue >= n:  # no case left for them: the device's prefilter skips them
                case_of[ended] = -1
                case_d.assign(case_of.astype(np.int32))
            elif ended:
                ws = np.array(sorted(ended))[:n - queue]
                cases = np.arange(queue, queue + len(ws))
                queue += len(ws)
                if len(ws) < len(ended):
                    case_of[sorted(ended)[len(ws):]] = -1
                take(ws, cases)
                c_of[ws] = 0
                R_after[ws, 0] = [releases[i].pose.R for i in cases]
                t_after[ws, 0] = [releases[i].pose.t for i in cases]
                active = np.union1d(active, ws)
            t3 = time.perf_counter()
            stats.step_s += t2 - t1
            stats.rules_s += t3 - t2
            if launched == 1:
                stats.first_chunk_s += t3 - t1
            else:
                stats.run_s += t3 - t1
    out = []
    for i, (s, r) in enumerate(zip(slots, releases)):
        if r.result is not None:
            out.append(r.result)
            continue
        if i in diverged:
            # A world whose state stopped being finite (its solver out of constraint rows, say)
            # is simulated again on MuJoCo C, and counted as a fallback.
            stats.fallbacks += 1
            stats.diverged += 1
            # From the predicted pose again, with the scene's judge and model already made.
            out.append(_simulate_c(Release(r.structure, r.part, r.pose, r.floor_y, config, r.judge), s.scene, config))
            continue
        model = s.scene.model
        host = mujoco.MjData(model)
        host.qpos[:] = end_qpos[i]
        host.qpos[:3] += s.floor
        mujoco.mj_forward(model, host)
        out.append(r.finish(_pose_of(host, s.scene.part_body), _touched(host, s.scene), int(stopped[i])))
    return out


__all__ = ["BATCH", "CONSTRAINTS_PER_WORLD", "CONTACTS_PER_WORLD", "MjxStats", "PART_SLOTS", "REFILLS", "STRUCTURE_SLOTS", "default_device",
           "settle_many"]

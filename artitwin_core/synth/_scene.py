"""The scene's geometry: a room, a cabinet with its moving parts and their contents, as meshes.

Canonical frame: y up (gravity along -y), floor at y = 0, the cabinet's front face at z = 0
looking towards +z, centred on x = 0. Every object is a triangle mesh in its own local frame plus
``world_from_local`` (its pose when closed); textures are evaluated in that local frame so they
move with the object. Parts move by :func:`part_motion` (the true motion, effects included);
:func:`joint_transform` is the ideal motion a :class:`~artitwin_core.joints.Joint` describes.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field

import numpy as np

from artitwin_core.geometry import axis_angle_to_matrix, make_se3
from artitwin_core.synth._spec import SceneSpec

STATIC_LABEL = -1
HAND_LABEL = -2
UP = np.array([0.0, 1.0, 0.0])
ROOM_HALF_WIDTH_M = 2.3
ROOM_FRONT_Z_M = 3.2
CEILING_M = 2.6
BOARD_M = 0.018  # panel thickness


def sub_rng(seed: int, purpose: str) -> np.random.Generator:
    """A generator for one purpose, independent of how much the others consumed."""
    return np.random.default_rng([int(seed), zlib.crc32(purpose.encode())])


@dataclass
class SceneObject:
    """One mesh with one texture. ``label``: -1 static, k >= 0 part k, -2 hand."""

    name: str
    vertices: np.ndarray  # [V, 3] metres, local frame
    triangles: np.ndarray  # [F, 3] int32
    texture: str
    params: dict
    label: int
    world_from_local: np.ndarray = field(default_factory=lambda: np.eye(4))


@dataclass
class Part:
    """One articulated part and how it really moves.

    ``axis``/``pivot`` are the nominal joint (canonical frame). ``grip`` is the point the hand
    holds and ``front`` the outward normal, both when closed. ``pitch`` (screw), ``sag_rad`` and
    ``tilt_rad`` are the joint effects (0 when absent); ``d_free`` points from the hinge to the free
    edge (doors); ``tilt_pivot`` is the drawer's back-bottom edge centre.
    """

    name: str
    joint_type: str  # "revolute" | "prismatic"
    axis: np.ndarray
    pivot: np.ndarray
    q_max: float
    grip: np.ndarray
    front: np.ndarray
    handle_dir: np.ndarray
    pitch: float = 0.0
    sag_rad: float = 0.0
    tilt_rad: float = 0.0
    d_free: np.ndarray | None = None
    tilt_pivot: np.ndarray | None = None


@dataclass
class SceneModel:
    objects: list[SceneObject]
    parts: list[Part]
    look_at: np.ndarray  # [3] what the cameras aim at
    light: np.ndarray  # [3] point light position
    size_m: tuple[float, float, float]


def _rot_about(point: np.ndarray, axis: np.ndarray, angle: float) -> np.ndarray:
    rot = axis_angle_to_matrix(axis, angle)
    return make_se3(rot, point - rot @ point)


def joint_transform(joint_type: str, axis, pivot, q: float, pitch: float = 0.0) -> np.ndarray:
    """``[4, 4]`` ideal motion of a joint at state ``q`` (radians or metres), canonical frame."""
    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    if joint_type == "prismatic":
        return make_se3(np.eye(3), axis * q)
    if joint_type == "fixed":
        return np.eye(4)
    out = _rot_about(np.asarray(pivot, dtype=np.float64), axis, q)
    if joint_type == "screw":
        out[:3, 3] += axis * pitch * q
    return out


def part_motion(part: Part, q: float) -> np.ndarray:
    """``[4, 4]`` true canonical-from-closed motion of ``part`` at state ``q``, effects included."""
    jt = "screw" if part.pitch else part.joint_type
    out = joint_transform(jt, part.axis, part.pivot, q, part.pitch)
    frac = q / part.q_max
    if part.joint_type == "revolute" and part.sag_rad:
        d_now = out[:3, :3] @ part.d_free
        droop_axis = np.cross(UP, d_now)
        droop_axis /= np.linalg.norm(droop_axis)
        out = _rot_about(out[:3, :3] @ part.pivot + out[:3, 3], droop_axis, part.sag_rad * frac) @ out
    if part.joint_type == "prismatic" and part.tilt_rad:
        tilt_axis = np.cross(UP, part.axis)
        tilt_axis /= np.linalg.norm(tilt_axis)
        out = out @ _rot_about(part.tilt_pivot, tilt_axis, part.tilt_rad * frac)
    return out


BOX_TRIANGLES = np.array(
    [[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7], [0, 1, 5], [0, 5, 4],
     [2, 3, 7], [2, 7, 6], [1, 2, 6], [1, 6, 5], [0, 4, 7], [0, 7, 3]],
    dtype=np.int32,
)  # outward-facing winding for the corner order below


def boxes(extents) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned boxes ``[(min [3], max [3]), ...]`` -> one mesh ``(vertices, triangles)``."""
    verts, tris = [], []
    for k, (lo, hi) in enumerate(extents):
        (x0, y0, z0), (x1, y1, z1) = lo, hi
        verts.append(
            [[x0, y0, z0], [x1, y0, z0], [x1, y1, z0], [x0, y1, z0],
             [x0, y0, z1], [x1, y0, z1], [x1, y1, z1], [x0, y1, z1]]
        )
        tris.append(BOX_TRIANGLES + 8 * k)
    return np.asarray(verts, dtype=np.float64).reshape(-1, 3), np.concatenate(tris)


def cylinder(radius: float, height: float, segments: int = 16) -> tuple[np.ndarray, np.ndarray]:
    """Closed cylinder along local y from 0 to ``height`` metres."""
    a = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    ring = np.stack([radius * np.cos(a), np.zeros_like(a), radius * np.sin(a)], -1)
    verts = np.concatenate([ring, ring + [0, height, 0], [[0, 0, 0], [0, height, 0]]])
    tris = []
    for i in range(segments):
        j = (i + 1) % segments
        tris += [[i, segments + i, j], [j, segments + i, segments + j]]
        tris += [[2 * segments, i, j], [2 * segments + 1, segments + j, segments + i]]
    return verts, np.asarray(tris, dtype=np.int32)


def sphere(radius: float, rings: int = 8, segments: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """UV sphere centred at the local origin."""
    th = np.linspace(0, np.pi, rings + 1)[1:-1]
    ph = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    t, p = np.meshgrid(th, ph, indexing="ij")
    body = np.stack([np.sin(t) * np.cos(p), np.cos(t), np.sin(t) * np.sin(p)], -1).reshape(-1, 3)
    verts = np.concatenate([[[0, 1, 0]], body, [[0, -1, 0]]]) * radius
    last = body.shape[0] + 1
    tris = []
    for j in range(segments):
        k = (j + 1) % segments
        tris.append([0, 1 + k, 1 + j])
        tris.append([last, 1 + (rings - 2) * segments + j, 1 + (rings - 2) * segments + k])
        for i in range(rings - 2):
            a, b = 1 + i * segments + j, 1 + i * segments + k
            tris += [[a, b, b + segments], [a, b + segments, a + segments]]
    return verts, np.asarray(tris, dtype=np.int32)


def _wood_params(rng: np.random.Generator, low_texture: bool) -> tuple[str, dict]:
    if low_texture:
        return "paint", {"color": [0.82, 0.82, 0.80], "seed": int(rng.integers(1 << 20)), "amp": 0.015}
    base = np.array([0.45, 0.26, 0.12]) * rng.uniform(0.8, 1.2)
    return "wood", {
        "color_a": (base * 1.25).tolist(),
        "color_b": (base * 0.55).tolist(),
        "seed": int(rng.integers(1 << 20)),
        "ring_freq": float(rng.uniform(14, 24)),
    }


def _interior_items(rng, lo, hi, label: int, prefix: str, min_y: float) -> list[SceneObject]:
    """A few objects standing on the floor ``y = min_y`` of the box ``lo..hi`` (canonical)."""
    items = []
    width = hi[0] - lo[0]
    slots = np.linspace(lo[0] + 0.18 * width, hi[0] - 0.18 * width, 3)
    room_h = hi[1] - min_y
    for k, x in enumerate(slots):
        kind = ("box", "can", "ball")[(k + int(rng.integers(3))) % 3]
        z = float(rng.uniform(lo[2] + 0.08, hi[2] - 0.12))
        color = rng.uniform(0.1, 0.9, 3).tolist()
        params = {"color": color, "color_b": rng.uniform(0.1, 0.9, 3).tolist(),
                  "seed": int(rng.integers(1 << 20)), "freq": 25.0}
        if kind == "box":
            sx, sz = rng.uniform(0.05, 0.09, 2)
            sy = min(rng.uniform(0.06, 0.2), 0.8 * room_h)
            v, t = boxes([((-sx, 0, -sz), (sx, sy, sz))])
        elif kind == "can":
            v, t = cylinder(float(rng.uniform(0.03, 0.05)), min(float(rng.uniform(0.08, 0.16)), 0.8 * room_h))
        else:
            r = min(float(rng.uniform(0.035, 0.06)), 0.4 * room_h)
            v, t = sphere(r)
            v = v + [0, r, 0]
        pose = make_se3(axis_angle_to_matrix(UP, float(rng.uniform(0, np.pi))), [x, min_y, z])
        items.append(SceneObject(f"{prefix}_{kind}{k}", v, t, "noise", params, label, pose))
    return items


def _rot_x_quarter(vertices: np.ndarray) -> np.ndarray:
    """Turn a mesh built along local y (``cylinder``) to point along +z."""
    return vertices @ axis_angle_to_matrix(np.array([1.0, 0.0, 0.0]), np.pi / 2).T


def handle_mesh(shape: str, vertical: bool, length: float, cx: float, face_z: float):
    """A handle on a front whose outer face is the plane ``z = face_z`` (local frame), centred at
    ``(cx, 0)``: ``(vertices, triangles, grip_z)`` or None for ``"none"``, and the z the hand grips.

    ``"bar"`` and ``"long-bar"`` are a grip bar on two standoffs, 3-4.5 cm proud of the face,
    ``length`` metres long (vertical or horizontal); ``"knob"`` a round knob 3.2 cm across.
    """
    if shape == "none":
        return None, face_z + 0.01
    if shape == "knob":
        v, t = cylinder(0.016, 0.028, segments=16)
        return (_rot_x_quarter(v) + [cx, 0.0, face_z], t), face_z + 0.02
    hl = length
    if vertical:
        v, t = boxes([
            ((cx - 0.01, -hl / 2, face_z + 0.03), (cx + 0.01, hl / 2, face_z + 0.045)),
            ((cx - 0.006, -hl / 2 + 0.01, face_z), (cx + 0.006, -hl / 2 + 0.025, face_z + 0.03)),
            ((cx - 0.006, hl / 2 - 0.025, face_z), (cx + 0.006, hl / 2 - 0.01, face_z + 0.03)),
        ])
    else:
        v, t = boxes([
            ((cx - hl / 2, -0.01, face_z + 0.03), (cx + hl / 2, 0.01, face_z + 0.045)),
            ((cx - hl / 2 + 0.01, -0.006, face_z), (cx - hl / 2 + 0.025, 0.006, face_z + 0.03)),
            ((cx + hl / 2 - 0.025, -0.006, face_z), (cx + hl / 2 - 0.01, 0.006, face_z + 0.03)),
        ])
    return (v, t), face_z + 0.0375


def build_scene(spec: SceneSpec) -> SceneModel:
    """The geometry of ``spec``'s scene, parts closed. Deterministic in ``spec.seed``."""
    rng = sub_rng(spec.seed, "layout")
    w, h, d = spec.size_m
    objects = _room(spec, rng)
    cab = _Cabinet(spec, rng, objects)
    split = _add_carcass(cab)
    if spec.furniture == "door":
        _add_door(cab, 0.0, h)
    elif spec.furniture == "drawer":
        _add_drawer(cab, split, h, moving=True)
        _add_drawer(cab, 0.0, split, moving=False)
    else:
        _add_door(cab, split, h)
        _add_drawer(cab, 0.0, split, moving=True)

    return SceneModel(
        objects=objects,
        parts=cab.parts,
        look_at=np.array([0.0, 0.55 * h, -0.1 * d]),
        light=np.array([0.7, CEILING_M - 0.15, 1.8]),
        size_m=(w, h, d),
    )


def _room(spec: SceneSpec, rng: np.random.Generator) -> list[SceneObject]:
    """Room: floor, ceiling, four walls with posters, and a crate beside the cabinet. Each wall's
    local x, y span its plane."""
    w, h, d = spec.size_m
    hw = w / 2
    objects: list[SceneObject] = []
    floor_v, floor_t = boxes([((-ROOM_HALF_WIDTH_M, -0.05, -d - 0.1), (ROOM_HALF_WIDTH_M, 0.0, ROOM_FRONT_Z_M))])
    objects.append(SceneObject("floor", floor_v, floor_t, "floor", {
        "color_a": [0.55, 0.40, 0.25], "color_b": [0.30, 0.20, 0.12], "seed": int(rng.integers(1 << 20))},
        STATIC_LABEL))
    ceil_v, ceil_t = boxes([((-ROOM_HALF_WIDTH_M, CEILING_M, -d - 0.1), (ROOM_HALF_WIDTH_M, CEILING_M + 0.05, ROOM_FRONT_Z_M))])
    objects.append(SceneObject("ceiling", ceil_v, ceil_t, "paint", {"color": [0.9, 0.9, 0.9], "seed": 1}, STATIC_LABEL))
    wall_len = {"back": 2 * ROOM_HALF_WIDTH_M, "front": 2 * ROOM_HALF_WIDTH_M,
                "left": ROOM_FRONT_Z_M + d + 0.03, "right": ROOM_FRONT_Z_M + d + 0.03}
    wall_pose = {
        "back": make_se3(np.eye(3), [0, 0, -d - 0.03]),
        "front": make_se3(axis_angle_to_matrix(UP, np.pi), [0, 0, ROOM_FRONT_Z_M]),
        "left": make_se3(axis_angle_to_matrix(UP, np.pi / 2), [-ROOM_HALF_WIDTH_M, 0, (ROOM_FRONT_Z_M - d) / 2]),
        "right": make_se3(axis_angle_to_matrix(UP, -np.pi / 2), [ROOM_HALF_WIDTH_M, 0, (ROOM_FRONT_Z_M - d) / 2]),
    }
    wall_color = (np.array([0.78, 0.75, 0.68]) * rng.uniform(0.9, 1.05)).tolist()
    for name, length in wall_len.items():
        # Walls overrun the corners, floor and ceiling so no ray escapes through a crack.
        v, tr = boxes([((-length / 2 - 0.1, -0.1, -0.05), (length / 2 + 0.1, CEILING_M + 0.1, 0.0))])
        posters = []
        for _ in range(3):
            pw, ph = rng.uniform(0.35, 0.8), rng.uniform(0.4, 0.8)
            x0 = rng.uniform(-length / 2 + 0.1, length / 2 - pw - 0.1)
            y0 = rng.uniform(0.9, 2.3 - ph)
            if name == "back" and x0 < hw + 0.05 and x0 + pw > -hw - 0.05:
                y0 = max(y0, h + 0.15)  # keep posters above the cabinet, where they stay visible
            posters.append((float(x0), float(y0), float(x0 + pw), float(min(y0 + ph, 2.5))))
        objects.append(SceneObject(f"wall_{name}", v, tr, "wall", {
            "color": wall_color, "seed": int(rng.integers(1 << 20)), "posters": posters},
            STATIC_LABEL, wall_pose[name]))
    # A textured crate beside the cabinet gives registration something besides posters.
    side = float(rng.choice([-1.0, 1.0]))
    cs = rng.uniform(0.25, 0.4, 3)
    cv, ct = boxes([((-cs[0] / 2, 0, -cs[2] / 2), (cs[0] / 2, cs[1], cs[2] / 2))])
    objects.append(SceneObject("crate", cv, ct, "noise", {
        "color": [0.2, 0.35, 0.55], "color_b": [0.75, 0.6, 0.3], "seed": int(rng.integers(1 << 20)), "freq": 8.0},
        STATIC_LABEL, make_se3(axis_angle_to_matrix(UP, float(rng.uniform(-0.5, 0.5))),
                               [side * (hw + 0.45), 0, -d + cs[2] / 2 + 0.05])))
    return objects


@dataclass
class _Cabinet:
    """The cabinet being built: the spec, the layout's random stream (drawn from in build order),
    the scene's objects and parts so far, and the carcass's wood."""

    spec: SceneSpec
    rng: np.random.Generator
    objects: list[SceneObject]
    parts: list[Part] = field(default_factory=list)
    tex: str = ""
    tex_params: dict = field(default_factory=dict)
    metal: dict = field(default_factory=lambda: {"color": [0.55, 0.56, 0.58], "seed": 3})

    def __post_init__(self) -> None:
        self.low = self.spec.texture == "low-texture"
        self.effects = self.spec.resolved_effects


def _add_carcass(cab: _Cabinet) -> float | None:
    """Cabinet carcass: open-fronted box, front face at z = 0, with a divider where the furniture
    has two parts. Returns the divider's height (metres; None: no divider)."""
    spec = cab.spec
    w, h, d = spec.size_m
    hw, t = w / 2, BOARD_M
    cab.tex, cab.tex_params = _wood_params(cab.rng, cab.low)
    split = {"door": None, "drawer": 0.5 * h, "door+drawer": 0.3 * h}[spec.furniture]
    carcass = [
        ((-hw, 0, -d), (-hw + t, h, 0)), ((hw - t, 0, -d), (hw, h, 0)),
        ((-hw + t, 0, -d), (hw - t, t, 0)), ((-hw + t, h - t, -d), (hw - t, h, 0)),
        ((-hw + t, t, -d), (hw - t, h - t, -d + t)),
    ]
    if split is not None:
        carcass.append(((-hw + t, split - t / 2, -d + t), (hw - t, split + t / 2, 0)))
    v, tr = boxes(carcass)
    cab.objects.append(SceneObject("cabinet", v, tr, cab.tex, cab.tex_params, STATIC_LABEL))
    return split


def _add_door(cab: _Cabinet, y0: float, y1: float) -> None:
    """A door hinged on a random side, covering the cabinet from ``y0`` to ``y1`` metres, with its
    handle, and shelves and contents behind it."""
    spec, rng, objects = cab.spec, cab.rng, cab.objects
    w = spec.size_m[0]
    hw, front_m = w / 2, spec.front_thickness_m
    k = len(cab.parts)
    hinge = float(rng.choice([-1.0, 1.0]))  # -1: hinge on the left edge (x = -w/2)
    axis = np.array([0.0, hinge, 0.0])  # positive q swings the free edge outwards (+z)
    gap = spec.hinge_gap_m
    pivot = np.array([hinge * (hw - gap), (y0 + y1) / 2, 0.0])
    pose = make_se3(np.eye(3), pivot)
    # Door in its local frame: hinge line at x = 0, free edge towards x = -hinge * w.
    xs = sorted([0.0, -hinge * (w - 0.003 - gap)])
    dv, dt = boxes([((xs[0], y0 + 0.002 - pivot[1], 0), (xs[1], y1 - 0.002 - pivot[1], front_m))])
    dtex, dparams = _wood_params(rng, cab.low)
    objects.append(SceneObject("door", dv, dt, dtex, dparams, k, pose))
    hx = -hinge * (w - gap - 0.07)
    length = min(0.16, 0.4 * (y1 - y0)) if spec.handle != "long-bar" else min(0.6, 0.7 * (y1 - y0))
    handle, grip_z = handle_mesh(spec.handle, True, length, hx, front_m)
    if handle is not None:
        objects.append(SceneObject("door_handle", *handle, "solid", cab.metal, k, pose))
    _add_door_interior(cab, y0, y1)
    part = Part(
        "door", "revolute", axis, pivot, float(spec.door_open_rad),
        grip=pivot + [hx, 0, grip_z], front=np.array([0.0, 0.0, 1.0]),
        handle_dir=UP.copy(), d_free=np.array([-hinge, 0.0, 0.0]),
    )
    if "screw_joint" in cab.effects:
        # Rise along gravity-up: the signed pitch is along the joint axis.
        part.pitch = float(cab.effects["screw_joint"]["rise_m_per_rad"]) * float(np.dot(axis, UP))
    if "axis_sag" in cab.effects:
        part.sag_rad = float(cab.effects["axis_sag"]["angle_rad"])
    cab.parts.append(part)


def _add_door_interior(cab: _Cabinet, y0: float, y1: float) -> None:
    """Shelves behind a door from ``y0`` to ``y1`` metres and the items on each level (static)."""
    spec, objects = cab.spec, cab.objects
    w, h, d = spec.size_m
    hw, t = w / 2, BOARD_M
    if spec.shelves:
        # Boards set back from the front, clear of the door's back face.
        step = (y1 - y0) / (spec.shelves + 1)
        ys = [y0 + step * (i + 1) for i in range(spec.shelves)]
        sv, st = boxes([((-hw + t, y - t / 2, -d + t), (hw - t, y + t / 2, -0.02)) for y in ys])
        objects.append(SceneObject("shelves", sv, st, cab.tex, cab.tex_params, STATIC_LABEL))
    if spec.interior_items:
        floor_y = y0 + (t / 2 if y0 > 0 else t)
        lo, hi = np.array([-hw + t, y0, -d + t]), np.array([hw - t, y1 - t, 0])
        if spec.shelves:  # the bottom level ends under the first shelf; then one level per shelf
            levels = [floor_y] + [y + t / 2 for y in ys]
            tops = [y - t / 2 for y in ys] + [y1 - t]
        else:
            levels, tops = [floor_y], [hi[1]]
        for i, (ly, ty) in enumerate(zip(levels, tops, strict=True)):
            objects.extend(_interior_items(
                sub_rng(spec.seed, "door_items" if i == 0 else f"door_items{i}"),
                lo, np.array([hi[0], ty, hi[2]]), STATIC_LABEL, "shelf" if i == 0 else f"shelf{i}", ly,
            ))


def _add_drawer(cab: _Cabinet, y0: float, y1: float, moving: bool) -> None:
    """A drawer front from ``y0`` to ``y1`` metres with its handle; a moving drawer also gets its
    box and contents, and a part (a fixed one is static scenery)."""
    spec, rng, objects = cab.spec, cab.rng, cab.objects
    w, h, d = spec.size_m
    hw, t, front_m = w / 2, BOARD_M, spec.front_thickness_m
    k = len(cab.parts) if moving else STATIC_LABEL
    name = "drawer" if moving else "drawer_fixed"
    ymid = (y0 + y1) / 2
    pivot = np.array([0.0, ymid, front_m])
    pose = make_se3(np.eye(3), pivot)
    fv, ft = boxes([((-hw + 0.003, y0 + 0.003 - ymid, -front_m), (hw - 0.003, y1 - 0.003 - ymid, 0))])
    ftex, fparams = _wood_params(rng, cab.low)
    objects.append(SceneObject(f"{name}_front", fv, ft, ftex, fparams, k, pose))
    length = min(0.25, 0.4 * w) if spec.handle != "long-bar" else min(0.7, 0.8 * w)
    handle, grip_z = handle_mesh(spec.handle, False, length, 0.0, 0.0)
    if handle is not None:
        objects.append(SceneObject(f"{name}_handle", *handle, "solid", cab.metal, k, pose))
    if not moving:
        return
    # The drawer box behind its front, in the same local frame (origin at the front's face).
    bt, x0, x1 = 0.012, -hw + t + 0.004, hw - t - 0.004
    # Clear of the board below (the carcass bottom, or half a divider).
    yb0, yb1 = y0 + (t if y0 == 0 else t / 2) + 0.004 - ymid, y1 - 0.03 - ymid
    zb0, zb1 = -(d - t - 0.01) - front_m, -front_m
    bv, btr = boxes([
        ((x0, yb0, zb0), (x1, yb0 + bt, zb1)), ((x0, yb0, zb0), (x0 + bt, yb1, zb1)),
        ((x1 - bt, yb0, zb0), (x1, yb1, zb1)), ((x0, yb0, zb0), (x1, yb1, zb0 + bt)),
    ])
    btex, bparams = _wood_params(rng, cab.low)
    objects.append(SceneObject("drawer_box", bv, btr, btex, bparams, k, pose))
    if spec.interior_items:
        items = _interior_items(sub_rng(spec.seed, "drawer_items"), np.array([x0 + bt, yb0, zb0 + bt]),
                                np.array([x1 - bt, yb1, zb1]), k, "drawer_item", yb0 + bt)
        for it in items:  # contents ride with the drawer, so they carry its label
            it.world_from_local = pose @ it.world_from_local
        objects.extend(items)
    part = Part(
        "drawer", "prismatic", np.array([0.0, 0.0, 1.0]), pivot.copy(), float(spec.drawer_open_m),
        grip=pivot + [0, 0, grip_z], front=np.array([0.0, 0.0, 1.0]),
        handle_dir=np.array([1.0, 0.0, 0.0]),
        tilt_pivot=pivot + [0, yb0, zb0],
    )
    if "drawer_tilt" in cab.effects:
        part.tilt_rad = float(cab.effects["drawer_tilt"]["angle_rad"])
    cab.parts.append(part)

"""Collision of the characters' shapes with the world, and compliant contact forces.

Geometry. Each shape is probed by points or segments with a radius:
  against the ground plane: a sphere by its centre, a capsule by its two end spheres (a capsule's
  deepest points against a plane are its ends; both ends support a capsule lying flat), a box by
  its 8 corners;
  against a static box: a sphere by its centre, a capsule by the sphere at the point of its axis
  segment nearest the box (golden-section search on the convex box distance), a box by its corners.
Which probes exist is static (it follows the shape types), where they are follows the model's
arrays, so shape sizes stay differentiable.

Force, per contact (a probe against one object), with signed distance φ (negative inside),
outward normal n and contact point x on the probe's surface moving at velocity v:
  normal     f_n = max(0, −k φ − c v·n)  when φ < 0
  friction   a stick spring whose stretch s integrates the contact point's tangential (slip)
             velocity, s ← s + Δt v_t: f_t = −k_t s − c_t v_t, limited to |f_t| ≤ μ f_n; when
             the limit binds the contact slides and s is held at μ f_n / k_t. The stretch is state
             (`State.contact_stretch`), so a box on an incline with tan θ < μ stays put instead of
             creeping as a regularised Coulomb law would, and a rolling ball (no slip) rolls on.
Forces enter the dynamics as spatial forces on the links, in link coordinates. Every branch is a
`jnp.where` between finite values and norms are guarded at zero, so gradients are finite.
"""

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from jaxsim import kinematics
from jaxsim.model import Model, Topology
from jaxsim.spatial import mat_vec, transpose
from jaxsim.world import World

# The 8 corners of a box as multiples of its half-extents.
BOX_CORNERS = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)],
                        float)
_GOLDEN_ITERATIONS = 16


@dataclasses.dataclass(frozen=True)
class Probes:
    """Static probe table: per probe the link, the two segment ends as multiples of the shape's
    half-sizes in the shape frame (equal ends for points), and whether it has the shape's radius."""

    link: np.ndarray
    end_a: np.ndarray
    end_b: np.ndarray
    rounded: np.ndarray

    def __len__(self):
        return len(self.link)


def _probes(topology: Topology, against_box: bool) -> Probes:
    link, end_a, end_b, rounded = [], [], [], []

    def add(i, a, b, r):
        link.append(i), end_a.append(a), end_b.append(b), rounded.append(r)

    for i, shape in enumerate(topology.shape_types):
        if shape == "sphere":
            add(i, (0, 0, 0), (0, 0, 0), True)
        elif shape == "capsule" and against_box:
            add(i, (0, -1, 0), (0, 1, 0), True)
        elif shape == "capsule":
            add(i, (0, -1, 0), (0, -1, 0), True)
            add(i, (0, 1, 0), (0, 1, 0), True)
        elif shape == "box":
            for corner in BOX_CORNERS:
                add(i, corner, corner, False)
    return Probes(np.array(link, np.int32), np.array(end_a, float).reshape(-1, 3),
                  np.array(end_b, float).reshape(-1, 3), np.array(rounded, bool))


@dataclasses.dataclass(frozen=True)
class ContactLayout:
    """Which contacts exist: ground probes against the ground, box probes against each box.

    Contacts are ordered ground first, then box 1's, box 2's, …; `link` and `obj` give each
    contact's link and object index (0 = ground, k = box k)."""

    ground: Probes
    box: Probes
    n_boxes: int
    use_ground: bool

    @functools.cached_property
    def link(self) -> np.ndarray:
        parts = ([self.ground.link] if self.use_ground else []) + [self.box.link] * self.n_boxes
        return np.concatenate(parts) if parts else np.zeros(0, np.int32)

    @functools.cached_property
    def obj(self) -> np.ndarray:
        parts = ([np.zeros(len(self.ground), np.int32)] if self.use_ground else []) + \
            [np.full(len(self.box), k + 1, np.int32) for k in range(self.n_boxes)]
        return np.concatenate(parts) if parts else np.zeros(0, np.int32)

    def __len__(self):
        return len(self.link)


@functools.lru_cache(maxsize=None)
def _layout(topology: Topology, n_boxes: int, use_ground: bool) -> ContactLayout:
    return ContactLayout(_probes(topology, False), _probes(topology, True), n_boxes, use_ground)


def contact_layout(model: Model, world: World) -> ContactLayout:
    return _layout(model.topology, len(world.box_names), world.ground)


def _safe_norm(x):
    sq = jnp.sum(x * x, -1)
    positive = sq > 0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, sq, 1.0)), 0.0)


def _clip_norm(x, limit):
    """Scale the rows of x down to at most `limit` in length."""
    norm = _safe_norm(x)
    over = norm > limit
    return x * jnp.where(over, limit / jnp.where(over, norm, 1.0), 1.0)[..., None]


def _probe_segments(model: Model, probes: Probes, rot_w, pos_w):
    """World positions of each probe's segment ends (P, 3) and its radius (P,)."""
    links = probes.link
    shape_rot, centre = kinematics.shape_poses(model, rot_w, pos_w)
    size = model.shape_size[links]

    def to_world(ends):
        offset = jnp.asarray(ends, size.dtype) * size
        return centre[links] + mat_vec(shape_rot[links], offset)

    radius = jnp.where(jnp.asarray(probes.rounded), size[:, 0], 0.0)
    return to_world(probes.end_a), to_world(probes.end_b), radius


def box_distance(point, center, rotation, half_size):
    """Signed distance from world points to a box (negative inside) and the outward normal."""
    local = mat_vec(transpose(rotation), point - center)             # Rᵀ (p − c)
    excess = jnp.abs(local) - half_size
    outside = jnp.maximum(excess, 0.0)
    out_dist = _safe_norm(outside)
    face = jax.nn.one_hot(jnp.argmax(excess, -1), 3, dtype=point.dtype)   # the nearest face
    # The largest excess picked by its face, not by `jnp.max`: max's derivative finds the
    # maximum by comparing it for equality with its operand, which XLA may compute again with
    # other rounding, and then divides by the zero matches it found (NaN gradients in float32
    # under unoptimised compilation, even where the point is outside and in_dist is 0).
    in_dist = jnp.minimum(jnp.sum(face * excess, -1), 0.0)
    sign = jnp.where(local < 0, -1.0, 1.0)
    out_normal = sign * outside / jnp.where(out_dist > 0, out_dist, 1.0)[..., None]
    normal_local = jnp.where((out_dist > 0)[..., None], out_normal, sign * face)
    return out_dist + in_dist, mat_vec(rotation, normal_local)


def _nearest_on_segment(a, b, center, rotation, half_size):
    """Point of each segment a–b nearest the box, by golden-section search on t ∈ [0, 1].

    The box's distance is convex along a line, so the search converges; the result is held
    constant for differentiation (the derivative of a minimum is the partial derivative at the
    minimiser), which keeps gradients exact and finite."""
    a, b = jax.lax.stop_gradient(a), jax.lax.stop_gradient(b)
    ratio = float((np.sqrt(5.0) - 1.0) / 2.0)    # (a Python float: keeps a float32 model float32)

    def distance(t):
        return box_distance(a + t[..., None] * (b - a), center, rotation, half_size)[0]

    def shrink(_, bracket):
        lo, hi = bracket
        left, right = hi - ratio * (hi - lo), lo + ratio * (hi - lo)
        go_left = distance(left) < distance(right)
        return jnp.where(go_left, lo, left), jnp.where(go_left, right, hi)

    lo, hi = jax.lax.fori_loop(0, _GOLDEN_ITERATIONS, shrink,
                               (jnp.zeros(a.shape[:-1], a.dtype), jnp.ones(a.shape[:-1], a.dtype)))
    return 0.5 * (lo + hi)


def contact_geometry(model: Model, world: World, rot_w, pos_w):
    """For every contact of the layout: the contact point x on the probe's surface (C, 3), the
    object's outward normal n there (C, 3) and the signed distance φ (C,), negative when the probe
    is inside the object; from the links' world poses."""
    layout = contact_layout(model, world)
    points, normals, gaps = [], [], []
    if world.ground:
        a, _, radius = _probe_segments(model, layout.ground, rot_w, pos_w)
        n = jnp.broadcast_to(world.ground_normal, a.shape)
        points.append(a - radius[:, None] * n)
        normals.append(n)
        gaps.append(jnp.sum(a * world.ground_normal, -1) - world.ground_offset - radius)
    if world.box_names:
        a, b, radius = _probe_segments(model, layout.box, rot_w, pos_w)

        def against(*box):
            t = _nearest_on_segment(a, b, *box)
            centre = a + t[:, None] * (b - a)
            dist, n = box_distance(centre, *box)
            return centre - radius[:, None] * n, n, dist - radius

        x, n, gap = jax.vmap(against)(world.box_center, world.box_rotation, world.box_half_size)
        points.append(x.reshape(-1, 3))                  # box-major, as `ContactLayout` orders
        normals.append(n.reshape(-1, 3))
        gaps.append(gap.reshape(-1))
    return jnp.concatenate(points), jnp.concatenate(normals), jnp.concatenate(gaps)


def point_velocities(rot_w, pos_w, v_body, links, points):
    """World velocities of world points fixed to the given links (body velocities [ω; v])."""
    r, o, v = rot_w[links], pos_w[links], v_body[links]
    local = mat_vec(transpose(r), points - o)                           # Rᵀ (x − o)
    return mat_vec(r, v[:, 3:] + jnp.cross(v[:, :3], local))


def _sum_groups(values, groups, count):
    """Σ of the rows of `values` (C, ...) in each of `count` groups → (count, ...), where
    `groups` (C,) is a NumPy array known when tracing (the contact layout). Written as static
    slices and adds: a scatter-add or a one-hot `dot` runs slowly over a batch on CPU."""
    groups = np.asarray(groups)
    zero = jnp.zeros(values.shape[1:], values.dtype)
    return jnp.stack([sum((values[c] for c in np.flatnonzero(groups == g)), zero)
                      for g in range(count)])


def link_wrenches(rot_w, pos_w, links, points, forces, n_links):
    """Spatial forces [x × f; f] on each link (n_links, 6), in link coordinates, from world
    forces applied at world points; `links` (C,) is static (NumPy), as in `ContactLayout`."""
    r, o = rot_w[links], pos_w[links]
    f_local = mat_vec(transpose(r), forces)
    x_local = mat_vec(transpose(r), points - o)
    wrench = jnp.concatenate([jnp.cross(x_local, f_local), f_local], -1)
    return _sum_groups(wrench, links, n_links)


def contact_forces(model: Model, world: World, rot_w, pos_w, v_body, stretch, dt):
    """Contact forces of the current state.

    Returns (f_ext (n_links, 6) link-frame spatial forces, the friction springs' next stretch
    (C, 3), and which link touches which object, a (n_links, n_objects) boolean array)."""
    layout = contact_layout(model, world)
    x, n, gap = contact_geometry(model, world, rot_w, pos_w)
    v = point_velocities(rot_w, pos_w, v_body, layout.link, x)
    touching = gap < 0
    v_n = jnp.sum(v * n, -1)
    f_n = jnp.where(touching, jnp.maximum(
        -world.contact_stiffness * gap - world.contact_damping * v_n, 0.0), 0.0)

    def tangential(u):
        return u - jnp.sum(u * n, -1, keepdims=True) * n

    friction = world.friction if jnp.ndim(world.friction) == 0 else \
        world.friction[np.asarray(layout.obj)]                          # one per object
    limit = friction * f_n
    v_t = tangential(v)
    stretch = _clip_norm(tangential(stretch) + dt * v_t,              # slides past μ f_n / k_t
                         limit / world.tangent_stiffness)
    f_t = _clip_norm(-world.tangent_stiffness * stretch - world.tangent_damping * v_t, limit)
    f_t = jnp.where(touching[:, None], f_t, 0.0)
    next_stretch = jnp.where(touching[:, None], stretch, 0.0)
    force = f_n[:, None] * n + f_t
    f_ext = link_wrenches(rot_w, pos_w, layout.link, x, force, model.n_links)
    n_objects = len(world.object_names)
    hits = _sum_groups(touching.astype(x.dtype), np.asarray(layout.link) * n_objects
                       + np.asarray(layout.obj), model.n_links * n_objects)
    return f_ext, next_stretch, hits.reshape(model.n_links, n_objects) > 0

"""Take-off states (thesis §3.3, §3.6.1): where a jump policy's episodes start, and what BDS explores.

The take-off frame of a reference run-up clip is "midway through the last support phase before
becoming airborne": a foot is in support in a clip frame when its ankle is within
`SUPPORT_HEIGHT` of the lowest the ankles get in the clip; the flight is the longest run of
frames with neither foot in support (the jump that ends both of the thesis's reference runs); the
support phase is the run of frames just before it in which the foot supporting the character at
the last frame before the flight is the only foot in support; the take-off frame is its middle
frame, and that foot is the take-off foot. Single support, because the jump takes off from one
leg (§3.6.1) and every other link touching the ground is a failure: the box-jump run plants its
right foot beside its left for 0.1 s (1.37–1.43 s) before the left alone pushes off, and a
take-off state inside that double support starts with its free foot on the ground. The curved
sprint has no double support, so its frame is the same either way.

The facing-direction-invariant frame at take-off. DeepMimic's characters face along their root's
X axis, so the frame's axes are, in the world:
    x  the facing direction: the root's X axis projected on the ground, normalised;
    y  the global up (+Y);
    z  x × y: the character's right.
Velocities in this frame are the world vectors rotated by the heading (`heading_rotation`): for
the root, ω = (ω_x, ω_y, ω_z) its angular velocity, v = (v_x, v_y, v_z) the velocity of its
origin. Positive ω_y turns the character to its left (counter-clockwise seen from above); the
curved sprint turns to its right at its end (ω_y = −3.2 rad/s at 3.30 s, −3.5 at 3.50 s in this
frame), so the thesis's "3 rad/s, taken from the reference curved sprint" is ω_y = −3 here;
v_z < 0 moves the character to its left (the sprint's −1.1 m/s at take-off; Table 3.3's v_z are
all negative). ω_x < 0 rolls its head to its left, towards the bar of α = 0, as the Fosbury
flop's row (ω_x = −3) does.

The take-off state is the clip's pose at the take-off frame put down on the take-off foot
(`grounded`), with the explored features x overwriting the root's velocities and the take-off
leg's joint velocities changed so that the planted foot stays put (`planted`); everything else —
v_x, v_y (unless a jump task's `vertical_velocity` sets it), the other joints' velocities — is
the clip's:
    high jump  x = (α, ω_x, ω_z, v_z), with ω_y = −3 rad/s;
    obstacle   x = (ω_x, ω_y, ω_z).
α, the approach angle, turns the bar and the mat about the take-off point, not the character:
the bar's plane has the horizontal normal n(α) = (sin α, 0, −cos α) in the facing frame (the
thesis's wall line x sin α − z cos α = 0, moved along n by `bar_distance`, 1.2 m, or by
`bar_time`'s rule: `agents.tasks.jump.bar_plane_distance`), so α = 0 is a bar on the
character's left along its running direction, crossed sideways (the Fosbury flop's row), and
α = π/2 a bar straight ahead.

Tables 3.3 and 3.4 of the thesis give the take-off states of the strategies found; their rows in
x are `HIGHJUMP_ROWS` and `OBSTACLE_ROWS`. The thesis does not state its search box; round values
that rows sit on read as its faces. The search bounds (`HIGHJUMP_BOUNDS`, `OBSTACLE_BOUNDS`)
contain every row: Table 3.4's side kick sits on 3.00 rad/s in two components, Table 3.3's rows
on v_z = −2.40 and −0.50 m/s, α = 2.09 (2π/3) and ω_x = −3.00. `HIGHJUMP_BOUNDS` is the wider of
two readings of Table 3.3: its rows also sit on ω_x = 1.00 (three of them, none above) and
ω_z = ±1.00 (one each, none beyond), which read as the box ω_x ∈ [−3, 1], ω_z ∈ [−1, 1], 2/9 of
ours in volume (a search's `[box]` sets it; docs/discovery/README.md, "A search in the narrower
box").
"""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from agents.config import ConfigError
from agents.tasks.observations import heading_rotation
from jaxsim import contact, kinematics, motion, rotations
from jaxsim.world import make_world

SUPPORT_HEIGHT = 0.05          # m above the lowest ankle height of the clip
HIGHJUMP_OMEGA_Y = -3.0        # rad/s, the curved sprint's turning rate at take-off
HIGHJUMP_FEATURES = ("alpha", "omega_x", "omega_z", "v_z")
OBSTACLE_FEATURES = ("omega_x", "omega_y", "omega_z")

# Table 3.3 (v_z, ω_x, ω_z, α) and Table 3.4 (ω_x, ω_y, ω_z), as x.
HIGHJUMP_ROWS = {
    "fosbury_flop": (-0.05, -3.00, 1.00, -2.40),
    "western_roll": (2.09, 1.00, -1.00, -0.50),
    "straddle": (1.65, 1.00, 0.88, -2.21),
    "front_kick": (0.45, 1.00, -0.26, -0.52),
    "side_dive": (1.18, -2.78, -0.32, -1.83),
    "side_jump": (0.70, -1.44, 0.44, -1.99),
}
OBSTACLE_ROWS = {
    "front_kick": (1.15, -1.11, 3.89),
    "side_kick": (3.00, 3.00, -2.00),
    "twist_jump_clockwise": (-1.50, 1.50, -2.00),
    "straddle": (0.00, 0.00, 1.00),
    "twist_jump_counterclockwise": (-2.67, 0.00, -1.44),
    "dive_turn": (-0.74, -2.15, -0.41),
}
HIGHJUMP_BOUNDS = ((-np.pi / 6, -3.0, -3.0, -2.4), (2 * np.pi / 3, 3.0, 3.0, -0.5))
OBSTACLE_BOUNDS = ((-3.0, -3.0, -4.0), (3.0, 3.0, 4.0))
BOUNDS = {"highjump": HIGHJUMP_BOUNDS, "obstacle": OBSTACLE_BOUNDS}     # by task


@dataclasses.dataclass(frozen=True)
class TakeoffFrame:
    """The take-off of a clip: its time (s), the take-off foot, the support phase (s)."""

    time: float
    foot: str
    support: tuple[float, float]
    flight: tuple[float, float]


def support_flags(model, clip, feet):
    """Frame times (F,) and, per frame and foot, whether the foot is in support (F, len(feet))."""
    times = np.asarray(clip.times)[:-1]
    poses = np.asarray(clip.poses)[:-1]
    links = np.array([model.topology.link_index(foot) for foot in feet])
    positions = jax.jit(jax.vmap(lambda q: kinematics.forward_kinematics(model, q)[1]))(poses)
    heights = np.asarray(positions)[:, links, 1]   # (compiled and vmapped: 1 s a clip, not 12)
    return times, heights <= heights.min() + SUPPORT_HEIGHT


def _runs(flags):
    """(start, stop) index pairs of the runs of True in a 1-D boolean array."""
    padded = np.concatenate([[False], flags, [False]]).astype(int)
    edges = np.flatnonzero(np.diff(padded))
    return list(zip(edges[::2], edges[1::2]))


def find_takeoff(model, clip, feet=("right_ankle", "left_ankle"), source="clip"):
    """The take-off frame of a run-up clip (see the module docstring); a ConfigError naming
    `source` when the clip has no flight preceded by a support phase or takes off from both
    feet."""
    times, support = support_flags(model, clip, feet)
    return takeoff_from_support(times, support, float(clip.duration), feet, source)


def takeoff_from_support(times, support, duration, feet, source="clip"):
    """`find_takeoff` from the frame times (F,) and support flags (F, len(feet)) of a clip."""
    flights = _runs(~support.any(axis=1))
    flights = [f for f in flights if f[0] > 0]
    if not flights:
        raise ConfigError(f"{source}: the clip never leaves the ground after a support phase")
    start, stop = max(flights, key=lambda f: f[1] - f[0])
    foot = int(np.argmax(support[start - 1]))
    alone = support[:, foot] & ~np.delete(support, foot, axis=1).any(axis=1)
    phase = [r for r in _runs(alone) if r[1] == start]
    if not phase:
        raise ConfigError(f"{source}: the clip takes off from both feet (both are in support "
                          f"at {times[start - 1]:.3f} s, the last frame before its flight)")
    first, last = phase[0][0], phase[0][1] - 1
    end = times[stop] if stop < len(times) else duration
    return TakeoffFrame(float(times[(first + last) // 2]), feet[foot],
                        (float(times[first]), float(times[last])),
                        (float(times[start]), float(end)))


def takeoff_start(model, clip, feet=("right_ankle", "left_ankle"), source="clip"):
    """(the take-off frame of a run-up clip, the take-off pose, the clip's velocity there): the
    pose is the clip's at the take-off frame put down on the take-off foot (`grounded`); a
    take-off state is this pose with the velocity `takeoff_velocity` makes of the clip's and x.
    The jump tasks start their episodes from it, and the run-up (`agents.tasks.runup`) aims at
    it."""
    frame = find_takeoff(model, clip, feet, source)
    q, qd = clip_state(model, clip, frame.time)
    # (compiled: op by op, the contact geometry took 5–20 s the first time in a process)
    return frame, jax.jit(grounded, static_argnums=2)(model, q, frame.foot), qd


def facing_velocities(q, qd):
    """The root's angular and linear velocity in the facing frame at pose q."""
    rot = rotations.quat_to_matrix(q[3:7])
    heading = heading_rotation(rot)
    return heading.T @ (rot @ qd[:3]), heading.T @ (rot @ qd[3:6])


def clip_vertical_velocity(q, qd):
    """The root's upward velocity of the clip's (q, qd) at the take-off frame: a jump task's
    default `vertical_velocity`. Computed eagerly (outside any trace) by every task that needs
    it, so that their take-off states agree bit for bit."""
    return facing_velocities(q, qd)[1][1]


def with_facing_velocities(q, qd, omega, velocity):
    """qd with the root's angular and linear velocity set to the given facing-frame vectors."""
    rot = rotations.quat_to_matrix(q[3:7])
    to_body = rot.T @ heading_rotation(rot)
    return qd.at[:3].set(to_body @ omega).at[3:6].set(to_body @ velocity)


def foot_velocity(model, q, qd, foot: int):
    """The world angular velocity and the world velocity of the origin of link `foot` (6,)."""
    rot, _, v = kinematics.link_states(model, q, qd)
    return jnp.concatenate([rot[foot] @ v[foot, :3], rot[foot] @ v[foot, 3:]])


def leg_dofs(model, foot: int) -> np.ndarray:
    """The velocity indices of the joints from the root (excluded) down to link `foot`."""
    topo, links = model.topology, []
    while foot > 0:
        links.append(foot)
        foot = topo.parents[foot]
    return np.concatenate([np.arange(topo.dof_offsets[i], topo.dof_offsets[i + 1])
                           for i in reversed(links)])


def planted(model, q, qd, foot: int):
    """qd with the joint velocities of the leg of `foot` changed, by the least change, so the
    foot does not move: its angular velocity and the velocity of its origin are zero.

    Overwriting the root's velocities with x sets the pelvis turning and sliding over a foot
    that, mid-support, stands on the ground; left as the clip had them, the leg's joints carry
    the foot along with the pelvis (at ω_x = −3 rad/s and a 0.9 m leg, about 3 m/s) and it
    leaves the ground before it can push. The foot's velocity is linear in qd: with J its
    columns for the leg (6 × 7 for hip, knee and ankle), the change is J⁺(−foot velocity)."""
    dofs = leg_dofs(model, foot)
    velocity = foot_velocity(model, q, qd, foot)
    jacobian = jax.jacfwd(lambda leg: foot_velocity(model, q, qd.at[dofs].set(leg), foot))(
        qd[dofs])
    return qd.at[dofs].add(jnp.linalg.pinv(jacobian) @ -velocity)


def takeoff_velocity(kind: str, model, q, qd, x, foot: int, vertical=None):
    """The take-off state's qd from the clip's (q, qd) at the take-off frame and x, with the
    root's upward velocity `vertical` (None: the clip's) and the take-off foot `foot` planted
    (`planted`)."""
    omega, velocity = facing_velocities(q, qd)
    if vertical is not None:
        velocity = velocity.at[1].set(jnp.asarray(vertical, qd.dtype))
    x = jnp.asarray(x, qd.dtype)
    if kind == "highjump":
        omega = jnp.stack([x[1], jnp.asarray(HIGHJUMP_OMEGA_Y, qd.dtype), x[2]])
        velocity = velocity.at[2].set(x[3])
    else:
        omega = x
    return planted(model, q, with_facing_velocities(q, qd, omega, velocity), foot)


def clip_state(model, clip, time):
    """The clip's pose and velocity at `time`."""
    return motion.sample_pose(clip, time), motion.sample_velocity(clip, time)


def foot_clearance(model, q, foot: str):
    """The height of the lowest ground probe of the link `foot` (its shape's lowest corner or
    surface point) above the ground plane y = 0, at pose q."""
    world = make_world(dtype=q.dtype)
    rot, pos = kinematics.forward_kinematics(model, q)
    *_, gaps = contact.contact_geometry(model, world, rot, pos)
    probes = contact.contact_layout(model, world).ground
    return jnp.min(gaps[:len(probes)][probes.link == model.topology.link_index(foot)])


def grounded(model, q, foot: str):
    """q moved vertically so that `foot` rests on the ground (its lowest point at y = 0).

    The release's run-up clips float above our ground: the curved sprint's ankles never come
    lower than 0.158 m, its feet's soles ~0.1 m up, and a take-off state taken from it as it
    is starts in the air, with nothing to push off. The take-off state is the clip's pose put
    down on its take-off foot."""
    return q.at[1].add(-foot_clearance(model, q, foot))


def check_x(kind: str, x, key: str):
    """x as a tuple of floats of the kind's length inside its bounds; a ConfigError naming `key`
    otherwise."""
    names, (lower, upper) = ((HIGHJUMP_FEATURES, HIGHJUMP_BOUNDS) if kind == "highjump"
                             else (OBSTACLE_FEATURES, OBSTACLE_BOUNDS))
    if len(x) != len(names):
        raise ConfigError(f"{key} must give {len(names)} numbers ({', '.join(names)}); got "
                          f"{len(x)}")
    for name, value, low, high in zip(names, x, lower, upper):
        if not (np.isfinite(value) and low - 1e-9 <= value <= high + 1e-9):
            raise ConfigError(f"{key}: {name} = {value} is outside the search bounds "
                              f"[{low:.3f}, {high:.3f}]")
    return tuple(float(v) for v in x)

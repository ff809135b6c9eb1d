"""A snake: a chain of capsules joined by spherical joints (the thesis's Snake1–3, Table 2.1)."""

from jaxsim.builder import LinkSpec, build_model
from jaxsim.characters.common import Y_TO_X


def snake(n_links: int = 10, segment_length: float = 0.3, radius: float = 0.05,
          segment_mass: float = 1.0, kp: float = 300.0, kd: float = 30.0, dtype=None):
    """A free-floating head segment followed by `n_links` segments on spherical joints.

    DoF = 6 + 3 n_links: snake(10), snake(22), snake(63) have 36, 72 and 195 DoF. The chain lies
    along +X in the rest pose. Each spherical joint is limited to ±1 rad per rotation-vector
    component and 200 N·m; the head, free, has neither.
    """
    if n_links < 1:
        raise ValueError(f"snake: n_links must be at least 1, got {n_links}")
    half = segment_length / 2 - radius
    body = dict(mass=segment_mass, shape="capsule", shape_pos=(segment_length / 2, 0, 0),
                shape_rot=Y_TO_X, shape_size=(radius, half, 0))
    links = [LinkSpec(name="head", parent=None, joint="free", **body)]
    for i in range(1, n_links + 1):
        links.append(LinkSpec(name=f"segment{i}", parent=links[-1].name, joint="spherical",
                              joint_pos=(segment_length, 0, 0), kp=kp, kd=kd,
                              torque_limit=200.0, q_lower=-1.0, q_upper=1.0, **body))
    kwargs = {} if dtype is None else {"dtype": dtype}
    return build_model(links, source=f"snake({n_links})", **kwargs)

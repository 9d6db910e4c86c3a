"""Universal Robots UR5e kinematics: DH forward kinematics, analytic inverse kinematics, and the
camera on the flange through a hand-eye transform. The package's one implementation of the arm's
kinematics, used by the simulated arm session, the viewpoint and hand–eye plans and the simulator.

Units: **metres and radians** (these poses face ROS and ``ur_rtde``). The base frame is the
frame of UR's DH model, the one the controller reports TCP poses in (ROS ``base``); the flange
frame is DH frame 6 (ROS ``tool0``). Poses are (4, 4) float64 ``T_base_x``.

The inverse kinematics follows the standard closed form for UR arms (K. Hawkins, "Analytic
Inverse Kinematics for the Universal Robots UR-5/UR-10 Arms", 2013): two shoulder branches x two
wrist branches x two elbow branches = up to 8 solutions.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import ArmError
from ..pose import invert_pose
from ..validation import check_array
from .tool import DEFAULT_T_FLANGE_CAMERA_M

TWO_PI = 2.0 * math.pi


def _default_lower() -> tuple[float, ...]:
    return (-TWO_PI, -TWO_PI, -math.pi, -TWO_PI, -TWO_PI, -TWO_PI)


def _default_upper() -> tuple[float, ...]:
    return (TWO_PI, TWO_PI, math.pi, TWO_PI, TWO_PI, TWO_PI)


@dataclass(frozen=True)
class URParams:
    """DH parameters (metres) and joint limits (radians) of a UR arm; defaults are the UR5e.

    Joint limits follow ``ur_description``'s UR5e: +-2 pi on every joint except the elbow
    (+-pi, where the arm would hit itself).
    """

    d1: float = 0.1625
    a2: float = -0.425
    a3: float = -0.3922
    d4: float = 0.1333
    d5: float = 0.0997
    d6: float = 0.0996
    lower: tuple[float, ...] = field(default_factory=_default_lower)
    upper: tuple[float, ...] = field(default_factory=_default_upper)

    def dh_table(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(a, d, alpha): three (6,) float64 arrays of the standard DH convention (m, m, rad)."""
        a = np.array([0.0, self.a2, self.a3, 0.0, 0.0, 0.0])
        d = np.array([self.d1, 0.0, 0.0, self.d4, self.d5, self.d6])
        alpha = np.array([math.pi / 2, 0.0, 0.0, math.pi / 2, -math.pi / 2, 0.0])
        return a, d, alpha


UR5E = URParams()

# Elbow up, tool pointing straight down in front of the robot (+x): a neutral seed for IK.
HOME_JOINTS = np.array([math.pi, -math.pi / 2, math.pi / 2, -math.pi / 2, -math.pi / 2, 0.0])

# Cost of moving each joint when choosing among IK solutions (base joints dominate).
JOINT_WEIGHTS = np.array([1.0, 1.0, 1.0, 0.5, 0.5, 0.1])


def dh_transform(theta: float, a: float, d: float, alpha: float) -> np.ndarray:
    """(4, 4) float64 standard DH link transform ``Rz(theta) Tz(d) Tx(a) Rx(alpha)``."""
    ct, st = math.cos(theta), math.sin(theta)
    ca, sa = math.cos(alpha), math.sin(alpha)
    return np.array([[ct, -st * ca, st * sa, a * ct],
                     [st, ct * ca, -ct * sa, a * st],
                     [0.0, sa, ca, d],
                     [0.0, 0.0, 0.0, 1.0]])


def link_frames(joints: np.ndarray, params: URParams = UR5E) -> np.ndarray:
    """Poses of DH frames 1..6 in the base frame.

    Args:
        joints: (6,) joint angles, radians.
        params: the arm.

    Returns:
        (6, 4, 4) float64 ``T_base_i`` for i = 1..6 (translation in metres); the last is the
        flange.
    """
    q = check_array("joints", joints, ndim=1, shape=(6,), dtype_kind="fiu")
    a, d, alpha = params.dh_table()
    frames = np.empty((6, 4, 4))
    pose = np.eye(4)
    for i in range(6):
        pose = pose @ dh_transform(float(q[i]), a[i], d[i], alpha[i])
        frames[i] = pose
    return frames


def forward_kinematics(joints: np.ndarray, params: URParams = UR5E) -> np.ndarray:
    """(4, 4) float64 flange-to-base pose (metres) for (6,) joint angles in radians."""
    return link_frames(joints, params)[-1]


def _wrap(angle: float) -> float:
    """Angle in (-pi, pi]."""
    return math.pi - (math.pi - angle) % TWO_PI


def _plus_minus(angle: float) -> tuple[float, ...]:
    """(angle, -angle), or (0,) alone: the two branches of an acos, without a duplicate."""
    return (angle, -angle) if angle != 0.0 else (angle,)


def _shoulder_angles(t06: np.ndarray, p: URParams) -> list[float]:
    """theta1 candidates (0 or 2): the wrist centre P05 must lie d4 off the base z axis."""
    p05 = t06 @ np.array([0.0, 0.0, -p.d6, 1.0])
    radius = math.hypot(p05[0], p05[1])
    if radius < abs(p.d4):
        return []
    psi = math.atan2(p05[1], p05[0])
    phi = math.acos(min(1.0, p.d4 / radius))
    return [_wrap(psi + phi + math.pi / 2), _wrap(psi - phi + math.pi / 2)]


def _elbow_solutions(t06: np.ndarray, q1: float, q5: float, q6: float,
                     p: URParams) -> list[np.ndarray]:
    """(q2, q3, q4) completions of (q1, q5, q6): the planar 3R chain of joints 2-4."""
    a, d, alpha = p.dh_table()
    t01 = dh_transform(q1, a[0], d[0], alpha[0])
    t45 = dh_transform(q5, a[4], d[4], alpha[4])
    t56 = dh_transform(q6, a[5], d[5], alpha[5])
    t14 = invert_pose(t01) @ t06 @ invert_pose(t45 @ t56)
    p13 = (t14 @ np.array([0.0, -p.d4, 0.0, 1.0]))[:3]
    r2 = float(p13 @ p13)
    cos_q3 = (r2 - p.a2**2 - p.a3**2) / (2.0 * p.a2 * p.a3)
    if abs(cos_q3) > 1.0 + 1e-12:
        return []
    solutions = []
    for q3 in _plus_minus(math.acos(max(-1.0, min(1.0, cos_q3)))):
        q2 = -math.atan2(p13[1], -p13[0]) + math.asin(p.a3 * math.sin(q3) / math.sqrt(r2))
        t13 = dh_transform(q2, a[1], d[1], alpha[1]) @ dh_transform(q3, a[2], d[2], alpha[2])
        t34 = invert_pose(t13) @ t14
        q4 = math.atan2(t34[1, 0], t34[0, 0])
        solutions.append(np.array([q1, _wrap(q2), q3, q4, q5, q6]))
    return solutions


def inverse_kinematics(flange_to_base_m: np.ndarray, params: URParams = UR5E,
                       q6_if_singular: float = 0.0) -> np.ndarray:
    """All joint solutions reaching a flange pose (limits not applied).

    Args:
        flange_to_base_m: (4, 4) float flange pose in the base frame, translation in metres.
        params: the arm.
        q6_if_singular: wrist-3 angle (rad) used when the wrist is singular (sin q5 = 0) and q6
            is not determined.

    Returns:
        (k, 6) float64 joint angles in (-pi, pi], radians, 0 <= k <= 8 (k = 0: unreachable).
    """
    t06 = check_array("flange_to_base_m", flange_to_base_m, ndim=2, shape=(4, 4),
                      dtype_kind="fiu").astype(np.float64)
    rot, pos = t06[:3, :3], t06[:3, 3]
    solutions: list[np.ndarray] = []
    for q1 in _shoulder_angles(t06, params):
        s1, c1 = math.sin(q1), math.cos(q1)
        cos_q5 = (pos[0] * s1 - pos[1] * c1 - params.d4) / params.d6
        if abs(cos_q5) > 1.0 + 1e-12:
            continue
        for q5 in _plus_minus(math.acos(max(-1.0, min(1.0, cos_q5)))):
            s5 = math.sin(q5)
            if abs(s5) < 1e-10:
                q6 = q6_if_singular
            else:
                q6 = math.atan2((-rot[0, 1] * s1 + rot[1, 1] * c1) / s5,
                                (rot[0, 0] * s1 - rot[1, 0] * c1) / s5)
            solutions.extend(_elbow_solutions(t06, q1, q5, q6, params))
    return np.array(solutions).reshape(-1, 6)


def _nearest_within_limits(solution: np.ndarray, seed: np.ndarray,
                           params: URParams) -> np.ndarray | None:
    """The 2-pi-equivalent of ``solution`` closest to ``seed`` joint by joint, or None."""
    out = np.empty(6)
    for j in range(6):
        options = solution[j] + TWO_PI * np.arange(-2, 3)
        options = options[(options >= params.lower[j]) & (options <= params.upper[j])]
        if options.size == 0:
            return None
        out[j] = options[np.argmin(np.abs(options - seed[j]))]
    return out


def solve_ik(flange_to_base_m: np.ndarray, seed: np.ndarray = HOME_JOINTS,
             params: URParams = UR5E, *, min_wrist_sin: float = 0.05) -> np.ndarray:
    """The IK solution within joint limits closest to ``seed``.

    Closeness is the weighted sum of absolute joint changes, ``JOINT_WEIGHTS``: moving the base
    and shoulder costs more than turning the last wrist, so a change of in-plane camera rotation
    never flips the arm into another configuration.

    Args:
        flange_to_base_m: (4, 4) flange pose in the base frame, metres.
        seed: (6,) joint angles (rad) to stay close to, e.g. the current configuration.
        params: the arm.
        min_wrist_sin: solutions with |sin q5| below this are rejected as wrist-singular.

    Returns:
        (6,) float64 joint angles, radians.

    Raises:
        ArmError: the pose is out of reach, only reachable near the wrist singularity, or only
            outside the joint limits; the message says which.
    """
    seed = check_array("seed", seed, ndim=1, shape=(6,), dtype_kind="fiu")
    raw = inverse_kinematics(flange_to_base_m, params, q6_if_singular=float(seed[5]))
    if raw.shape[0] == 0:
        raise ArmError("unreachable: flange pose is out of the arm's reach")
    regular = raw[np.abs(np.sin(raw[:, 4])) >= min_wrist_sin]
    if regular.shape[0] == 0:
        raise ArmError("unreachable: every solution is at the wrist singularity (|sin q5| "
                       f"< {min_wrist_sin})")
    candidates = [c for c in (_nearest_within_limits(s, seed, params) for s in regular)
                  if c is not None]
    if not candidates:
        raise ArmError("unreachable: every solution violates the joint limits")
    return min(candidates, key=lambda c: float(JOINT_WEIGHTS @ np.abs(c - seed)))


def camera_pose(joints: np.ndarray, t_flange_camera_m: np.ndarray = DEFAULT_T_FLANGE_CAMERA_M,
                params: URParams = UR5E) -> np.ndarray:
    """(4, 4) float64 camera-to-base pose (metres) of the hand-held camera at ``joints`` (rad)."""
    return forward_kinematics(joints, params) @ t_flange_camera_m


def flange_pose_for_camera(camera_to_base_m: np.ndarray,
                           t_flange_camera_m: np.ndarray = DEFAULT_T_FLANGE_CAMERA_M
                           ) -> np.ndarray:
    """(4, 4) float64 flange-to-base pose (metres) that puts the camera at ``camera_to_base_m``."""
    return np.asarray(camera_to_base_m, dtype=np.float64) @ invert_pose(t_flange_camera_m)

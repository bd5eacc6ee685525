"""UOT three-axis turntable kinematics (docs/explanation/model.md#attitude-chain).

All functions are vectorised: angles have shape (..., 3) ordered (outer, middle,
inner) in radians, black-box angles shape (..., 3, 3) with rows (t->o0, o->m0,
m->i0) and columns (alpha, beta, gamma). Matrices are coordinate transforms
`C_a^b` (`v_b = C_a^b v_a`); row k of `C_t^b` is body axis k written in ENU.

A positive frame angle is a *negative* right-handed rotation about the frame
axis (the paper's "clockwise"), so a CCW turn has angular velocity +rate about
+Z_o, +Y_m or +Z_i.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from schedules.loader import Frame

FRAMES: tuple[Frame, Frame, Frame] = ("outer", "middle", "inner")

#: Frame axis in the frame's own coordinates.
FRAME_AXES = {
    "outer": np.array([0.0, 0.0, 1.0]),
    "middle": np.array([0.0, 1.0, 0.0]),
    "inner": np.array([0.0, 0.0, 1.0]),
}
ENU_LABELS = ("E", "N", "U")
ENU_NEGATIVE = ("W", "S", "D")


def triple(values: Iterable[float]) -> tuple[float, float, float]:
    """Three numbers (one per frame or axis) as a tuple of floats; ValueError for any other count."""
    a, b, c = (float(v) for v in values)
    return a, b, c


def _stack(rows) -> np.ndarray:
    """Equal-shaped arrays `rows[i][j]` as the matrices' element (i, j): shape (..., len(rows), len(rows[0]))."""
    first = np.asarray(rows[0][0])
    out = np.empty(first.shape + (len(rows), len(rows[0])), np.result_type(*(x for r in rows for x in r)))
    for i, row in enumerate(rows):
        for j, x in enumerate(row):
            out[..., i, j] = x
    return out


def rot_z(theta: np.ndarray) -> np.ndarray:
    """Outer/inner frame matrix of paper eqs. 2 and 4: [[c, -s, 0], [s, c, 0], [0, 0, 1]]."""
    c, s = np.cos(theta), np.sin(theta)
    zero, one = np.zeros_like(c), np.ones_like(c)
    return _stack([[c, -s, zero], [s, c, zero], [zero, zero, one]])


def rot_y(theta: np.ndarray) -> np.ndarray:
    """Middle frame matrix of paper eq. 3: [[c, 0, s], [0, 1, 0], [-s, 0, c]]."""
    c, s = np.cos(theta), np.sin(theta)
    zero, one = np.zeros_like(c), np.ones_like(c)
    return _stack([[c, zero, s], [zero, one, zero], [-s, zero, c]])


def black_box_matrix(angles: np.ndarray) -> np.ndarray:
    """Error rotation `R_y(alpha) R_x(beta) R_z(gamma)` (paper eq. 6, exact product).

    `angles` has shape (..., 3) = (alpha, beta, gamma) in radians.
    """
    angles = np.asarray(angles, dtype=float)
    a, b, g = angles[..., 0], angles[..., 1], angles[..., 2]
    ca, sa, cb, sb, cg, sg = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(g), np.sin(g)
    return _stack(
        [
            [ca * cg - sa * sb * sg, ca * sg + sa * sb * cg, -sa * cb],
            [-cb * sg, cb * cg, sb],
            [sa * cg + ca * sb * sg, sa * sg - ca * sb * cg, ca * cb],
        ]
    )


def _error_rotations(black_box: np.ndarray | None, batch: tuple) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`C_t^o0`, `C_o^m0`, `C_m^i0` (identity on an ideal table)."""
    if black_box is None:
        eye = np.broadcast_to(np.eye(3), batch + (3, 3))
        return eye, eye, eye
    bb = black_box_matrix(np.asarray(black_box, dtype=float))
    return bb[..., 0, :, :], bb[..., 1, :, :], bb[..., 2, :, :]


def frame_chain(angles: np.ndarray, black_box: np.ndarray | None = None,
                mounting: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """The partial products of eq. 5 that everything else is built from.

    Returns `C_o^b`, `C_m^b` (the inner side of each frame, mapping that frame's
    coordinates to body) and `C_t^b`, plus `C_t^o0` (the outer side of the outer
    frame) for the Earth terms of a turn.
    """
    angles = np.asarray(angles, dtype=float)
    c_to0, c_om0, c_mi0 = _error_rotations(black_box, angles.shape[:-1])
    c_i = rot_z(angles[..., 2])
    c_m = rot_y(angles[..., 1])
    c_o = rot_z(angles[..., 0])
    c_ib = c_i if mounting is None else np.asarray(mounting) @ c_i
    c_mb = c_ib @ c_mi0            # m -> b
    c_ob = c_mb @ c_m @ c_om0      # o -> b
    c_tb = c_ob @ c_o @ c_to0      # t -> b
    return {"C_m^b": c_mb, "C_o^b": c_ob, "C_t^b": c_tb, "C_t^o0": c_to0}


def attitude(angles: np.ndarray, black_box: np.ndarray | None = None,
             mounting: np.ndarray | None = None) -> np.ndarray:
    """`C_t^b` for frame angles (rad), eq. 5, optional black box and mounting `C_i^b`."""
    return frame_chain(angles, black_box, mounting)["C_t^b"]


def frame_axes_in_body(angles: np.ndarray, black_box: np.ndarray | None = None,
                       mounting: np.ndarray | None = None) -> np.ndarray:
    """Unit axes of the outer, middle and inner frames in body coordinates, shape (..., 3, 3).

    Row j is frame j's axis; a CCW turn of frame j rotates the body by +angle about it.
    """
    return _frame_axes(frame_chain(angles, black_box, mounting), mounting)


def _frame_axes(chain: dict[str, np.ndarray], mounting: np.ndarray | None) -> np.ndarray:
    """`frame_axes_in_body` from the `frame_chain` of the angles."""
    axis_o = chain["C_o^b"] @ FRAME_AXES["outer"]
    axis_m = chain["C_m^b"] @ FRAME_AXES["middle"]
    # Z_i is fixed in the inner frame: only the mounting moves it in body axes.
    axis_i_body = FRAME_AXES["inner"] if mounting is None else np.asarray(mounting) @ FRAME_AXES["inner"]
    axis_i = np.broadcast_to(axis_i_body, axis_o.shape)
    return np.stack([axis_o, axis_m, axis_i], axis=-2)


def body_rate_from_frame_rates(angles: np.ndarray, frame_rates: np.ndarray,
                               black_box: np.ndarray | None = None,
                               mounting: np.ndarray | None = None) -> np.ndarray:
    """Body angular velocity relative to the ground from frame angle rates (rad/s).

    `frame_rates` are d(angle)/dt in the paper's convention; a CCW turn has a
    negative angle rate and a positive rotation about the frame axis.
    """
    return _body_rate(frame_axes_in_body(angles, black_box, mounting), frame_rates)


def _body_rate(axes: np.ndarray, frame_rates: np.ndarray) -> np.ndarray:
    return -np.einsum("...j,...jk->...k", np.asarray(frame_rates, dtype=float), axes)


def attitude_and_body_rate(angles: np.ndarray, frame_rates: np.ndarray, black_box: np.ndarray | None = None,
                           mounting: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(`attitude`, `body_rate_from_frame_rates`) of the same angles from one `frame_chain` (the same numbers)."""
    chain = frame_chain(angles, black_box, mounting)
    return chain["C_t^b"], _body_rate(_frame_axes(chain, mounting), frame_rates)


def axis_along(vector: np.ndarray, tol: float = 1e-6) -> tuple[int, int] | None:
    """(index, sign) of the coordinate axis a unit vector lies along within `tol`, else None."""
    vector = np.asarray(vector, dtype=float)
    k = int(np.argmax(np.abs(vector)))
    if abs(abs(vector[k]) - 1.0) > tol:
        return None
    return k, (1 if vector[k] > 0 else -1)


def pointing_labels(c_tb: np.ndarray, tol: float = 1e-6) -> str:
    """Body X, Y, Z pointing as ENU letters, e.g. 'E N U' or 'S U W'.

    An axis halfway between two or three geographic axes (a tilt of 45 deg) is printed as their letters joined by
    '+', e.g. 'E+U'; any other axis that is not along a geographic axis within `tol` as '?'.
    """
    labels = []
    for row in np.asarray(c_tb):
        along = axis_along(row, tol)
        if along is None:
            parts = [k for k in range(3) if abs(row[k]) > tol]
            equal = all(abs(abs(row[k]) - abs(row[parts[0]])) <= tol for k in parts)
            labels.append("+".join(ENU_LABELS[k] if row[k] > 0 else ENU_NEGATIVE[k] for k in parts)
                          if equal else "?")
        else:
            k, sign = along
            labels.append(ENU_LABELS[k] if sign > 0 else ENU_NEGATIVE[k])
    return " ".join(labels)


def split_at_frame(angles: np.ndarray, frame_index: int, black_box: np.ndarray | None = None,
                   mounting: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(L, R) with `C_t^b = L @ F(theta) @ R` for the frame `frame_index` (0 outer, 1 middle, 2 inner).

    `F` is that frame's own matrix (rot_z or rot_y); L and R do not change while only
    that frame turns, which is what makes a turn's integrals closed-form.
    """
    angles = np.asarray(angles, dtype=float)
    batch = angles.shape[:-1]
    eye = np.broadcast_to(np.eye(3), batch + (3, 3))
    c_to0, c_om0, c_mi0 = _error_rotations(black_box, batch)
    c_m = rot_y(angles[..., 1])
    c_o = rot_z(angles[..., 0])
    mount = eye if mounting is None else np.broadcast_to(np.asarray(mounting, dtype=float), batch + (3, 3))
    c_i = rot_z(angles[..., 2])
    if frame_index == 0:
        return mount @ c_i @ c_mi0 @ c_m @ c_om0, c_to0
    if frame_index == 1:
        return mount @ c_i @ c_mi0, c_om0 @ c_o @ c_to0
    if frame_index == 2:
        return mount, c_mi0 @ c_m @ c_om0 @ c_o @ c_to0
    raise ValueError(f"frame_index must be 0, 1 or 2, got {frame_index}")


def frame_matrix_parts(frame_index: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(P, A, B) with the frame matrix `F(theta) = P + cos(theta) A + sin(theta) B`."""
    if frame_index in (0, 2):
        return (np.diag([0.0, 0.0, 1.0]), np.diag([1.0, 1.0, 0.0]),
                np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]]))
    if frame_index == 1:
        return (np.diag([0.0, 1.0, 0.0]), np.diag([1.0, 0.0, 1.0]),
                np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 0.0], [-1.0, 0.0, 0.0]]))
    raise ValueError(f"frame_index must be 0, 1 or 2, got {frame_index}")

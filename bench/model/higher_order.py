"""Higher-order IMU errors beyond the 30-coefficient model (docs/explanation/model.md#higher-order-terms, issue 30).

Each term is an input-equivalent error added before the scale factor, per sensor s with input
`u_s = Eg_s . w_b` (gyro) or `a_s = Ea_s . f_s` (accelerometer, `f_s` the specific force at its own place):

    gyro s:   F_s = Kg_s (u_s + G_s . f_b + A_s/2 |u_s| + N_s u_s^2 + D0_s)
    accel s:  J_s = Ka_s (a_s + B_s/2 |a_s| + Q_s a_s^2 + sum_j!=s C_sj a_s f_sj + K0_s)
    f_s(t) = f_b(t - tau) + dw/dt x r_s + w x (w x r_s)   (all at t - tau; tau < 0: the gyros' inputs at t + tau)

G: gyro g-sensitivity (3x3, rows gyros, columns body X Y Z); A, B: scale-factor asymmetry
((K+ - K-) / K, so a positive input sees K (1 + A/2), a negative one K (1 - A/2)); N: gyro
scale-factor nonlinearity (quadratic in the input rate); Q: accelerometer second-order coefficient;
C: its cross terms with the body axes (zero diagonal; for an accelerometer whose pendulous and output
axes are body axes these are IEEE 1293's K_ip and K_io); r_s: accelerometer s's position from the
rotation centre (size effect and mounting offset); tau: the accelerometers' delay behind the gyros (negative: the
gyros are late, so that the simulator never looks ahead of the motion it has been told).

Internally SI (rad/s per m/s^2, 1/(rad/s), 1/(m/s^2), m, s); `from_display`/`to_display` use the
configuration's units (deg/h per g, ppm, ppm per deg/s, ug/g^2, mm, ms).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from bench.model.units import DEG, DEG_PER_HOUR, G0, MICRO_G

PPM = 1e-6

#: display name -> (shape, SI per display unit, unit)
DISPLAY_FIELDS: dict[str, tuple[tuple[int, ...], float, str]] = {
    "gyro_g_sensitivity_dph_per_g": ((3, 3), DEG_PER_HOUR / G0, "deg/h per g"),
    "gyro_asymmetry_ppm": ((3,), PPM, "ppm"),
    "gyro_nonlinearity_ppm_per_dps": ((3,), PPM / DEG, "ppm per deg/s"),
    "acc_asymmetry_ppm": ((3,), PPM, "ppm"),
    "acc_second_order_ug_per_g2": ((3,), MICRO_G / G0 ** 2, "ug/g^2"),
    "acc_cross_ug_per_g2": ((3, 3), MICRO_G / G0 ** 2, "ug/g^2"),
    "acc_lever_arm_mm": ((3, 3), 1e-3, "mm"),
    "time_offset_ms": ((), 1e-3, "ms"),
}
#: display name -> the dataclass field
_FIELD_OF = {"gyro_g_sensitivity_dph_per_g": "gyro_g_sensitivity", "gyro_asymmetry_ppm": "gyro_asymmetry",
             "gyro_nonlinearity_ppm_per_dps": "gyro_nonlinearity", "acc_asymmetry_ppm": "acc_asymmetry",
             "acc_second_order_ug_per_g2": "acc_second_order", "acc_cross_ug_per_g2": "acc_cross",
             "acc_lever_arm_mm": "acc_lever_arm", "time_offset_ms": "time_offset_s"}


def _zeros(*shape: int):
    return field(default_factory=lambda: np.zeros(shape))


@dataclass
class HigherOrderTerms:
    """The higher-order truth of a simulated IMU (SI); all zero: none."""

    gyro_g_sensitivity: np.ndarray = _zeros(3, 3)   # rad/s per m/s^2, rows gyros, columns body X Y Z
    gyro_asymmetry: np.ndarray = _zeros(3)          # (K+ - K-) / K
    gyro_nonlinearity: np.ndarray = _zeros(3)       # per rad/s: error N u^2
    acc_asymmetry: np.ndarray = _zeros(3)           # (K+ - K-) / K
    acc_second_order: np.ndarray = _zeros(3)        # per m/s^2: error Q a^2
    acc_cross: np.ndarray = _zeros(3, 3)            # per m/s^2: error C_sj a_s f_j, zero diagonal
    acc_lever_arm: np.ndarray = _zeros(3, 3)        # m, row s: accelerometer s's place in body axes
    time_offset_s: float = 0.0                      # the accelerometers lag the gyros by this

    def __post_init__(self) -> None:
        for display, (shape, _si, _unit) in DISPLAY_FIELDS.items():
            if shape:
                name = _FIELD_OF[display]
                setattr(self, name, np.asarray(getattr(self, name), dtype=float).reshape(shape))
        self.time_offset_s = float(self.time_offset_s)
        if np.any(np.diag(self.acc_cross) != 0.0):
            raise ValueError("acc_cross has a zero diagonal: an accelerometer's own square is acc_second_order")

    # -- which parts are on ---------------------------------------------------------------------------
    @property
    def enabled(self) -> bool:
        return self.has_lever_arms or self.time_offset_s != 0.0 or any(
            np.any(getattr(self, name) != 0.0) for name in ("gyro_g_sensitivity", "gyro_asymmetry",
                                                            "gyro_nonlinearity", "acc_asymmetry",
                                                            "acc_second_order", "acc_cross"))

    @property
    def has_lever_arms(self) -> bool:
        return bool(np.any(self.acc_lever_arm != 0.0))

    # -- the model ------------------------------------------------------------------------------------
    def gyro_error(self, gyro_input: np.ndarray, specific_force: np.ndarray) -> np.ndarray:
        """Input-equivalent gyro errors (rad/s), (m, 3), for the gyros' inputs `Eg_s . w_b` (m, 3) in rad/s and
        the body specific force (m, 3) in m/s^2."""
        u = np.asarray(gyro_input)
        return (np.asarray(specific_force) @ self.gyro_g_sensitivity.T + 0.5 * self.gyro_asymmetry * np.abs(u)
                + self.gyro_nonlinearity * u * u)

    def acc_error(self, acc_input: np.ndarray, force_at_sensors: np.ndarray) -> np.ndarray:
        """Input-equivalent accelerometer errors (m/s^2), (m, 3), for the inputs `Ea_s . f_s` (m, 3) and the
        specific force at each accelerometer (m, 3 sensors, 3 body axes), m/s^2."""
        a = np.asarray(acc_input)
        cross = np.einsum("sj,msj->ms", self.acc_cross, np.asarray(force_at_sensors))
        return 0.5 * self.acc_asymmetry * np.abs(a) + self.acc_second_order * a * a + a * cross

    def lever_arm_force(self, body_rate: np.ndarray, body_rate_derivative: np.ndarray) -> np.ndarray:
        """The specific force each accelerometer sees beyond the centre's, (m, 3 sensors, 3 axes), m/s^2:
        tangential `dw/dt x r_s` plus centripetal `w x (w x r_s)` (w in rad/s, dw/dt in rad/s^2, body axes)."""
        w = np.asarray(body_rate)[:, None, :]
        r = self.acc_lever_arm[None, :, :]
        return np.cross(np.asarray(body_rate_derivative)[:, None, :], r) + np.cross(w, np.cross(w, r))

    # -- display units --------------------------------------------------------------------------------
    @classmethod
    def from_display(cls, values: dict[str, object]) -> "HigherOrderTerms":
        """From configuration units (`DISPLAY_FIELDS`); absent names are zero. Raises KeyError naming an
        unknown one, ValueError for a wrong shape."""
        kwargs: dict[str, object] = {}
        for name, value in values.items():
            shape, si, _unit = DISPLAY_FIELDS[name]
            array = np.asarray(value, dtype=float)
            if array.shape != shape:
                raise ValueError(f"{name} must have shape {shape}, has {array.shape}")
            kwargs[_FIELD_OF[name]] = float(array) * si if shape == () else array * si
        return cls(**kwargs)  # type: ignore[arg-type]

    def to_display(self) -> dict[str, object]:
        out: dict[str, object] = {}
        for name, (shape, si, _unit) in DISPLAY_FIELDS.items():
            value = getattr(self, _FIELD_OF[name])
            out[name] = float(value) / si if shape == () else (np.asarray(value) / si).tolist()
        return out


# Presets (display units). The magnitudes are the order of what public data sheets, the IEEE standards' models
# and the systematic-calibration simulations of PSINS (the reference) give for each class, as the comments
# say; where no public figure was found the comment says the value is our assumption. The signs and the spread
# between axes are ours, so that no two axes are alike (a solve that mixes axes up shows it).
GRADES: dict[str, dict[str, object]] = {
    # A navigation-grade FOG IMU with quartz pendulous accelerometers.
    "nav-fog": {
        # An interferometric FOG has no proof mass, so its g-sensitivity is a residual (IEEE 952's model keeps the
        # term): a few thousandths of a deg/h per g is our assumption, below the unit's bias instability.
        "gyro_g_sensitivity_dph_per_g": [[0.004, -0.002, 0.001], [0.002, 0.005, -0.003], [-0.001, 0.003, 0.006]],
        # Navigation-grade FOG scale factor is held to a few ppm overall; asymmetry of a few ppm (our assumption
        # within that budget).
        "gyro_asymmetry_ppm": [3.0, -2.0, 4.0],
        # ~10 ppm at 100 deg/s as a quadratic: 0.1 ppm per deg/s (our assumption, the scale-factor budget again).
        "gyro_nonlinearity_ppm_per_dps": [0.08, -0.05, 0.10],
        # Quartz pendulous accelerometers: the PSINS systematic-calibration simulation takes second-order terms of
        # 10-30 ug/g^2; the cross terms and asymmetry of the same order are our assumption.
        "acc_asymmetry_ppm": [10.0, -8.0, 12.0],
        "acc_second_order_ug_per_g2": [12.0, -8.0, 15.0],
        "acc_cross_ug_per_g2": [[0.0, 6.0, -4.0], [-5.0, 0.0, 7.0], [3.0, -6.0, 0.0]],
        # Three separate accelerometers a few cm from the unit's reference point (PSINS's simulation: inner lever
        # arms of 1-6 cm), the reference point on the rotation centre within a few mm.
        "acc_lever_arm_mm": [[25.0, 6.0, -4.0], [-5.0, 22.0, 7.0], [3.0, -8.0, 28.0]],
        # Gyro and accelerometer channels sampled by one clock: a filter-delay mismatch of tens of us (our
        # assumption).
        "time_offset_ms": 0.05,
    },
    # A tactical MEMS IMU (the Sensonor STIM class).
    "tactical-mems": {
        # MEMS gyros have a proof mass: Sensonor gives the STIM210's linear acceleration effect as 10 deg/h per g.
        "gyro_g_sensitivity_dph_per_g": [[8.0, -3.0, 2.0], [2.5, 10.0, -4.0], [-2.0, 3.5, 9.0]],
        # The STIM210's scale-factor accuracy is 500 ppm: an asymmetry of 100-200 ppm within it (our assumption).
        "gyro_asymmetry_ppm": [150.0, -120.0, 200.0],
        # The STIM210's nonlinearity is 25 ppm; read as the relative error at 200 deg/s of a quadratic term:
        # ~0.1 ppm per deg/s.
        "gyro_nonlinearity_ppm_per_dps": [0.12, -0.10, 0.15],
        # MEMS accelerometers give nonlinearity as ~0.1-1 % of a 10-40 g range; read as a quadratic that is of
        # order 100-250 ug/g^2; asymmetry of a few hundred ppm and cross terms of tens of ug/g^2 (our assumption).
        "acc_asymmetry_ppm": [300.0, -250.0, 400.0],
        "acc_second_order_ug_per_g2": [150.0, -100.0, 200.0],
        "acc_cross_ug_per_g2": [[0.0, 40.0, -30.0], [-35.0, 0.0, 50.0], [25.0, -45.0, 0.0]],
        # A small unit: the sensing elements lie within ~1 cm, mounted on the rotation centre within mm.
        "acc_lever_arm_mm": [[6.0, 2.0, -1.5], [-1.5, 5.0, 2.5], [1.0, -2.5, 7.0]],
        # Separate gyro and accelerometer filter chains: a group-delay mismatch of half a ms (our assumption).
        "time_offset_ms": 0.5,
    },
}
#: the choices of `grade`: "none" starts from zero
GRADE_NAMES = ("none", *GRADES)


def preset(grade: str) -> dict[str, object]:
    """A grade's display values (a copy; "none": empty)."""
    return {name: np.array(value).tolist() if isinstance(value, list) else value
            for name, value in GRADES.get(grade, {}).items()}


__all__ = ["DISPLAY_FIELDS", "GRADES", "GRADE_NAMES", "HigherOrderTerms", "preset"]

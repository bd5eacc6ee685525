"""What the solve knows beyond the data, from a bench configuration: bias stabilities, the budget's inputs."""

from __future__ import annotations

import numpy as np

from bench.errors import BenchError
from bench.model.observations import COUNT_RESOLUTION
from bench.model.table_prior import TablePrior, rms_arcsec
from bench.model.units import ARCSEC, DEG_PER_HOUR, MICRO_G
from bench.plan.compiler import own_turn_rates
from bench.solve.budget import BudgetInputs, gm_mean_kernel


def bias_stabilities(config, sim: bool) -> tuple[float | None, float | None]:
    """(gyro deg/h, accelerometer ug) bias instabilities the solver adds to the bias sigmas.

    A measured noise result (`[imu] noise = "FILE"`, from `bench noise`: the largest of
    the three axes' Allan bias instability) first; else the IMU identity's datasheet
    values; on the simulator with noise on, the simulated IMU's own where neither gives
    one (it is what its datasheet would say).
    """
    identity, noise = config.imu.identity, config.imu.noise
    if noise is not None:
        return noise.gyro_bias_stability_dph, noise.acc_bias_stability_ug
    gyro_stability, acc_stability = identity.gyro_bias_stability_dph, identity.acc_bias_stability_ug
    if sim and config.sim.noise.enabled:
        if gyro_stability is None:
            gyro_stability = config.sim.noise.gyro_bias_instability_dph
        if acc_stability is None:
            acc_stability = config.sim.noise.acc_bias_instability_ug
    return gyro_stability, acc_stability


def budget_inputs(config, sim: bool) -> BudgetInputs:
    """What the uncertainty budget knows beyond the data (`bench.solve.budget`), from the configuration.

    Bias instabilities as `bias_stabilities` (taken as the 1-sigma of a Gauss-Markov bias;
    its correlation time as `correlation_time_s`). The table's
    part from `[table]` (datasheet figure or table check); on the simulator without either,
    the simulated black box's RMS (what its datasheet would say). The turns' angle error as
    `turn_angle_sigma_rad`. The site's uncertainty from
    `[site]`, zero on the simulator (its world is the configured site exactly).
    """
    gyro, acc = bias_stabilities(config, sim)
    pointing = config.table.pointing
    if pointing is None and sim:
        written = config.sim.black_box_arcsec      # the RMS it was drawn with, or the nine angles as written
        rms = float(written) if isinstance(written, (int, float)) else rms_arcsec(config.sim.black_box_rad)
        pointing = TablePrior.uniform(rms, f"the simulated table's black-box RMS ({rms:.3g} arcsec per angle)")
    site = config.site
    return BudgetInputs(table=pointing, gyro_bias_instability=(gyro or 0.0) * DEG_PER_HOUR,
                        acc_bias_instability=(acc or 0.0) * MICRO_G,
                        correlation_time_s=correlation_time_s(config, sim),
                        gravity_sigma_mps2=0.0 if sim else site.gravity_sigma_mps2,
                        latitude_sigma_deg=0.0 if sim else site.latitude_sigma_deg,
                        turn_rate_dps=config.plan.turn_rate_dps,
                        turn_rates_dps=own_turn_rates(config.plan.rotations),
                        turn_angle_sigma_rad=turn_angle_sigma_rad(config, sim),
                        # an IMU rounding each sample (sbg-ecan) has no counter: its turns carry their own rounding
                        count_resolution=0.0 if config.imu.layout.time_stamp is not None else COUNT_RESOLUTION)


def turn_angle_sigma_rad(config, sim: bool) -> float | None:
    """1-sigma of each turn's angle error (rad): `[table] turn_angle_error_arcsec`; on the simulator without it
    zero (its table stops exactly where it is told: what its datasheet would say); else None (not known: the
    budget flags that its part is not included)."""
    configured = config.table.turn_angle_error_arcsec
    if configured is not None:
        return configured * ARCSEC
    return 0.0 if sim else None


def correlation_time_s(config, sim: bool) -> float:
    """The bias instability's correlation time: `[imu.identity] bias_correlation_time_s`, else the simulated
    IMU's on the simulator, else `DEFAULT_CORRELATION_TIME_S`.

    A noise result (`[imu] noise = FILE`) does not set it: its Allan fit averages over candidate
    Gauss-Markov times without pinning one down (a simulated 1 h record of a 300 s bias gave a weighted
    geometric mean of 30 s, its candidates 3-87 s), too far off to feed the budget."""
    configured = config.imu.identity.bias_correlation_time_s
    if configured is not None:
        return configured
    return config.sim.noise.correlation_time_s if sim else DEFAULT_CORRELATION_TIME_S


class SolveInputError(BenchError):
    """The configuration gives the solve something it cannot take (found before anything moves)."""


def check_solvable(config, steps, sim: bool) -> BudgetInputs:
    """What the solve will need from the configuration, built before anything moves (`bench run`, also
    `--dry-run`): the budget's inputs, the bias-instability kernel over the plan's observation windows (its
    dwells and turns, laid end to end at their estimated times) and the table prior's covariance, each finite
    and decomposable as the solve will decompose them. Returns the inputs; `SolveInputError` names what fails."""
    try:
        inputs = budget_inputs(config, sim)
    except (ValueError, ArithmeticError) as exc:
        raise SolveInputError(f"the uncertainty budget's inputs cannot be built from the configuration: {exc}") \
            from exc
    tau = inputs.correlation_time_s
    elapsed = 0.0
    starts: dict[str, list[float]] = {"dwell": [], "turn": []}
    durations: dict[str, list[float]] = {"dwell": [], "turn": []}
    for step in steps:
        if step.kind in starts:
            starts[step.kind].append(elapsed)
            durations[step.kind].append(step.estimated_s)
        elapsed += step.estimated_s
    with np.errstate(all="ignore"):     # a kernel that overflows is reported below, not warned about
        matrices = [(f"the bias-instability kernel of the {kind}s",
                     gm_mean_kernel(np.array(starts[kind]), np.array(durations[kind]), tau))
                    for kind in starts if starts[kind]]
    if inputs.table is not None:
        matrices.append(("the table prior's covariance", np.asarray(inputs.table.covariance_rad2, dtype=float)))
    for what, matrix in matrices:
        with np.errstate(all="ignore"):
            finite = bool(np.isfinite(matrix).all())
        if not finite:
            raise SolveInputError(f"{what} is not finite (bias correlation time {tau:g} s): the solve could not use "
                                  "it")
        try:
            np.linalg.eigh(0.5 * (matrix + matrix.T))
        except np.linalg.LinAlgError as exc:
            raise SolveInputError(f"{what} cannot be decomposed ({exc}): the solve could not use it") from exc
    return inputs


#: correlation time of the bias instability when nothing better is known (s)
DEFAULT_CORRELATION_TIME_S = 300.0

__all__ = ["DEFAULT_CORRELATION_TIME_S", "SolveInputError", "bias_stabilities", "budget_inputs", "check_solvable",
           "correlation_time_s", "turn_angle_sigma_rad"]

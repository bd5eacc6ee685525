"""The `[chamber]` section of a bench configuration: the thermal chamber's controller, limits and safe setpoint.

    [chamber]
    url = "sim"                  # or tcp://..., a serial device, modbus+tcp://..., modbus+rtu://...
    dialect = "ascii"            # ascii | modbus (docs/hardware/chamber.md); default: the url's (modbus+... -> modbus,
                                 # any other -> ascii)
    timeout_s = 1.0
    retries = 2
    poll_s = 1.0
    safe_setpoint_c = 23.0       # on abort or fault the chamber is sent here; absent: it is stopped
    [chamber.limits]
    min_setpoint_c = -40.0
    max_setpoint_c = 85.0
    max_ramp_c_per_min = 5.0
    # modbus: register_map = "watlow-f4" (the default), "generic", "file.toml", or an inline
    # [chamber.modbus] table (docs/hardware/chamber.md)

The section is optional (a configuration without it has no chamber; `BenchConfig.chamber` is None). Every problem is one
`ConfigError` ``file:line: key: message``, as for the rest of the file.

On the simulator (`url = "sim"`, or any url with `bench run --sim`) the simulated chamber is served in the dialect
and over the kind of link the url names: Modbus RTU on a pty for `modbus+rtu://...`, Modbus TCP for
`modbus+tcp://...`, ASCII lines on a pty for a serial device, ASCII over TCP for `tcp://...` and `sim`.
"""

from __future__ import annotations

from dataclasses import dataclass

from bench.config.device import SIM_URL, url_and_dialect
from bench.config.keys import MAX_RAMP_C_PER_MIN, allowed, integer, number
from bench.config.reader import Table, show, suggest
from bench.config.register_map import CHAMBER_MAP, register_map_value
from drivers.chamber import DIALECTS, ChamberLimits, check_url_dialect
from drivers.chamber.presets import ChamberMap
from drivers.transport import MODBUS_SCHEMES

CHAMBER_KEYS = allowed("chamber")
LIMIT_KEYS = allowed("chamber.limits")


@dataclass(frozen=True)
class ChamberConfig:
    """[chamber]: the controller, its limits, the safe setpoint and (Modbus) register map."""

    url: str
    dialect: str
    timeout_s: float
    retries: int
    poll_s: float
    limits: ChamberLimits
    safe_setpoint_c: float | None            # None: on abort or fault the chamber is stopped
    register_map: ChamberMap | None  # modbus only; None = the default map (watlow-f4)

    @property
    def is_sim(self) -> bool:
        return self.url == SIM_URL

    @property
    def sim_link(self) -> str:
        """Where the simulator serves this chamber: 'pty' for a serial url (Modbus RTU or an ASCII serial
        device), 'tcp' for a TCP url and for `sim` (`bench.sim.chamber_server.serve_chamber`'s `where`)."""
        if self.url == SIM_URL or self.url.startswith(("tcp://", "modbus+tcp://")):
            return "tcp"
        return "pty"

    def driver_options(self) -> dict:
        """Keyword arguments of `drivers.chamber.open_chamber` (besides url and dialect)."""
        options: dict = {"limits": self.limits, "timeout_s": self.timeout_s, "retries": self.retries}
        if self.register_map is not None:
            options["register_map"] = self.register_map
        return options


def _limits(t: Table) -> ChamberLimits:
    low, high = (number(t, "chamber.limits", key) for key in ("min_setpoint_c", "max_setpoint_c"))
    if not low < high:
        raise t.error("max_setpoint_c", f"must be above min_setpoint_c ({low:g} degC), got {high:g}")
    ramp = number(t, "chamber.limits", "max_ramp_c_per_min")
    return ChamberLimits(low, high, ramp)


def chamber_config(t: Table) -> ChamberConfig:
    """The checked [chamber] section (its url and dialect are required)."""
    url, dialect = url_and_dialect(t, "chamber", DIALECTS, check_url_dialect,
                                   lambda name: f"unknown chamber dialect {show(name)}" + suggest(name, DIALECTS),
                                   implied=lambda url: "modbus" if url.startswith(MODBUS_SCHEMES) else "ascii")
    timeout_s = number(t, "chamber", "timeout_s")
    retries = integer(t, "chamber", "retries")
    assert retries is not None
    poll_s = number(t, "chamber", "poll_s")
    limits = _limits(t.table("limits", LIMIT_KEYS))
    safe = t.number("safe_setpoint_c", None, ge=limits.min_setpoint_c, le=limits.max_setpoint_c, unit="degC")
    register_map = register_map_value(t, dialect, "chamber", CHAMBER_MAP)
    return ChamberConfig(url, dialect, timeout_s, retries, poll_s, limits, safe, register_map)


__all__ = ["CHAMBER_KEYS", "MAX_RAMP_C_PER_MIN", "ChamberConfig", "SIM_URL", "chamber_config"]

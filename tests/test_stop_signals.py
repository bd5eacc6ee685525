"""Fail safe, round two (issue 34): the stop the bench reports is the stop it made; no stop signal is lost.

The lost-controller case end to end against `bench sim rig` is in tests/test_sim_rig.py.
Subprocess runs are few and bounded; nothing here asserts on wall time.
"""

from __future__ import annotations

from drivers.errors import TurntableConnectionError
from drivers.turntable import TABLE_STATE_UNKNOWN, StopOutcome, open_turntable
from drivers.turntable.scpi import ScpiTurntable


class _Refusing(ScpiTurntable):
    """An SCPI client whose controller takes the abort (`abort_works`) but not the controlled stop."""

    abort_works = True

    def _stop(self) -> None:
        raise TurntableConnectionError("link lost")

    def _abort(self) -> None:
        if not self.abort_works:
            raise TurntableConnectionError("link lost")


# -- 1. safe_stop / safe_abort say what happened --------------------------------------------------

def test_safe_stop_and_abort_of_an_unreachable_controller_say_table_state_unknown():
    table = open_turntable("tcp://127.0.0.1:1", "scpi", timeout_s=0.2, retries=0)
    for result in (table.safe_stop(), table.safe_abort()):
        assert result.outcome is StopOutcome.UNKNOWN and result.unknown
        assert isinstance(result.error, TurntableConnectionError)
        assert result.describe().startswith(TABLE_STATE_UNKNOWN)
        assert "abort sent" not in result.describe()


def test_a_failed_controlled_stop_with_the_abort_taken_says_abort_sent():
    table = _Refusing("tcp://127.0.0.1:1")
    result = table.safe_stop()
    assert result.outcome is StopOutcome.ABORT_SENT and not result.unknown
    assert result.describe() == "controlled stop failed (TurntableConnectionError: link lost); abort sent (servos off)"
    table.abort_works = False
    result = table.safe_stop()
    assert result.unknown and TABLE_STATE_UNKNOWN in result.describe() and "abort failed" in result.describe()

"""What a simulated run's modules load when they start (issue 35: every `bench run --sim` pays for it): not
scipy.signal, scipy.stats or scipy.optimize (half a second, for a first-order filter, a chi-square tail and fits
the run does not make), nor the simulated servers and codecs of the table dialects the run does not speak."""

from __future__ import annotations

import json
import subprocess
import sys

from tests.helpers.run import REPO

#: imports what `bench run` imports when it runs a plan, then prints the modules then loaded
_PROBE = """
import json, sys
import bench.cli.run, bench.run.devices, bench.run.runner, bench.solve.inputs, bench.solve.methods
import bench.log.reader, bench.report.markdown, bench.verify.plan
print(json.dumps(sorted(sys.modules)))
"""


def _loaded() -> set[str]:
    done = subprocess.run([sys.executable, "-c", _PROBE], cwd=REPO, capture_output=True, text=True, timeout=120,
                          stdin=subprocess.DEVNULL)
    assert done.returncode == 0, done.stderr
    return set(json.loads(done.stdout.splitlines()[-1]))


def test_a_simulated_runs_modules_start_without_what_the_default_run_never_uses():
    loaded = _loaded()
    assert not loaded & {"scipy.signal", "scipy.stats", "scipy.optimize"}, sorted(loaded)
    unused_dialects = {"bench.sim.acutrol_server", "bench.sim.mn_server", "drivers.turntable.acutrol_codec",
                       "drivers.turntable.mn_codec"}
    assert not loaded & unused_dialects, sorted(loaded & unused_dialects)
    assert {"bench.sim.world", "bench.sim.scpi_server", "scipy.special"} <= loaded     # (the probe sees imports)

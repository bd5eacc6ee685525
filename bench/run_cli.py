"""`bench run`: an unattended calibration run, on hardware or on the simulator.

Exit codes: 0 done (quality checks passed); 2 usage or configuration error, or the
table/IMU cannot be reached (nothing moved); 3 hardware fault or aborted (Ctrl-C, e-stop,
timeout; the table is stopped and the log kept: `--resume LOG` continues it); 4 the run
finished but a quality check failed (the report says which).
"""

from __future__ import annotations

import argparse
import json
import secrets
import signal
import sys
import time
from contextlib import ExitStack
from pathlib import Path

from bench import __version__

EXIT_OK, EXIT_USAGE, EXIT_FAULT, EXIT_QUALITY = 0, 2, 3, 4

#: The sequencer's loop periods on the simulator: coarse, because the simulated clock jumps.
SIM_OPTIONS = dict(move_poll_s=0.1, imu_poll_s=0.5, state_period_s=1.0)


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "run", help="run a calibration plan (hardware from --config, or the simulator with --sim)",
        description="Run a calibration plan unattended: move through the schedules, record everything to "
                    "MCAP, solve from the log, write result JSON and a report. Exit codes: 0 done, 2 usage or "
                    "configuration error (nothing moved), 3 hardware fault or aborted (table stopped; "
                    "--resume the log), 4 finished but a quality check failed.")
    parser.add_argument("--config", metavar="FILE", help="bench configuration (see bench.example.toml)")
    parser.add_argument("--sim", action="store_true",
                        help="run on the simulator: the built-in simulated bench, or --config's plan and [sim]")
    parser.add_argument("--dry-run", action="store_true", help="print the compiled steps and the estimated "
                                                               "duration; move nothing")
    parser.add_argument("--out", metavar="DIR", help="output folder (default: the config's [output] folder)")
    parser.add_argument("--resume", metavar="LOG", help="continue an interrupted run from its log")
    parser.add_argument("--operator", default="", help="who runs it (recorded in the log)")
    parser.add_argument("--quiet", action="store_true", help="no progress output")
    parser.set_defaults(func=cmd_run)


def _fail(message: str, code: int) -> int:
    print(f"bench run: {message}", file=sys.stderr)
    return code


def _load(args):
    from bench.config import default_sim_config, load_config

    if args.config:
        return load_config(args.config)
    if args.sim:
        return default_sim_config()
    raise ValueError("say --config FILE or --sim")


def _completed_units(resume: str | None) -> tuple[set[str], list[str]]:
    """Units complete in the log to resume, and the run id and logs of that run."""
    if not resume:
        return set(), []
    from bench.extract import finished_observation_steps
    from bench.logread import read_log

    log = read_log(resume)
    previous = json.loads(log.metadata.get("run", {}).get("previous_logs", "[]"))
    return set(finished_observation_steps(log.events)), [*previous, resume]


def _quality_failures(solution, stats_live) -> list[str]:
    failures = list(solution.extraction.problems) + list(solution.damage)
    outliers = solution.calibration.quality().get("outliers", [])
    if outliers:
        failures.append(f"{len(outliers)} residual outliers beyond the outlier threshold")
    if stats_live.lost_samples:
        failures.append(f"IMU link lost samples: {stats_live.summary()}")
    return failures


def cmd_run(args: argparse.Namespace) -> int:
    from bench.config import ConfigError
    from bench.logread import LogError
    from bench.plan import PlanError, PlanTiming, compile_plan

    if args.config and args.resume is None and args.sim is False and not Path(args.config).exists():
        return _fail(f"{args.config}: no such file", EXIT_USAGE)
    try:
        config = _load(args)
        completed, previous_logs = _completed_units(args.resume)
    except (ConfigError, LogError, ValueError, OSError) as exc:
        return _fail(str(exc), EXIT_USAGE)
    sim = args.sim or config.table.is_sim
    plan_cfg = config.plan
    try:
        timing = PlanTiming(dwell_s=plan_cfg.dwell_s, settle_s=plan_cfg.settle_s, move_rate_dps=plan_cfg.move_rate_dps,
                            move_accel_dps2=plan_cfg.move_accel_dps2, turn_rate_dps=plan_cfg.turn_rate_dps,
                            turn_accel_dps2=plan_cfg.turn_accel_dps2, rest_s=plan_cfg.rest_s,
                            revolutions=plan_cfg.revolutions)
        plan = compile_plan(plan_cfg.positions, plan_cfg.rotations, timing, limits=config.table.limits,
                            order=plan_cfg.order)
    except (PlanError, ValueError) as exc:
        return _fail(f"plan: {exc}", EXIT_USAGE)
    if args.dry_run:
        print(plan.format_dry_run())
        if completed:
            print(f"resume: {len(completed)} units complete in {args.resume} would be skipped: "
                  f"{', '.join(sorted(completed))}")
        return EXIT_OK
    with ExitStack() as stack:
        return _run(args, config, plan, sim, completed, previous_logs, stack)


def _open_devices(config, sim: bool, stack: ExitStack):
    """(clock, turntable, IMU receiver, world or None); errors -> (message) via exceptions."""
    from drivers.clock import SYSTEM_CLOCK
    from drivers.imu.receiver import ImuReceiver
    from drivers.turntable import open_turntable

    world = None
    if sim:
        from bench.sim.world import SimWorld

        world = stack.enter_context(SimWorld(
            config.site.site, config.sim.imu, config.sim.noise, black_box_rad=config.sim.black_box_rad,
            dialect=config.table.dialect, imu_rate_hz=config.imu.rate_hz, layout=config.imu.layout,
            seed=config.sim.seed, register_map=config.table.register_map))
        clock, url, bus = world.clock, world.table_url, world.bus_config
    else:
        clock, url, bus = SYSTEM_CLOCK, config.table.url, config.imu.bus_kwargs()
    options = {"limits": config.table.limits, "clock": clock, "timeout_s": config.table.timeout_s,
               "retries": config.table.retries}
    if config.table.dialect == "modbus" and config.table.register_map is not None:
        options["register_map"] = config.table.register_map
    table = open_turntable(url, config.table.dialect, **options)
    table.connect()
    stack.callback(table.close)
    receiver = ImuReceiver(bus, config.imu.layout, config.imu.rate_hz)
    stack.callback(receiver.close)
    return clock, table, receiver, world


def _metadata(config, plan, run_id: str, args, sim: bool, previous_logs: list[str]) -> dict:
    from bench.steps import step_to_dict

    identity = config.imu.identity
    return {
        "run": {"run_id": run_id, "operator": args.operator, "software_version": __version__,
                "started_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                "mode": "simulator" if sim else "hardware", "previous_logs": json.dumps(previous_logs)},
        "config": {"toml": config.source_text, "path": str(config.path or "<built-in --sim>")},
        "site": {k: str(v) for k, v in config.site.site.to_dict().items()},
        "imu": {"model": identity.model, "serial": identity.serial, "rate_hz": str(config.imu.rate_hz),
                "interface": str(config.imu.interface), "channel": str(config.imu.channel),
                "dbc": config.imu.dbc.name},
        "plan": {"steps_json": json.dumps([step_to_dict(s) for s in plan.steps]),
                 "estimated_total_s": f"{plan.estimated_total_s:.1f}", "order": plan.order,
                 "positions": plan_name(config.plan.positions), "rotations": plan_name(config.plan.rotations)},
    }


def plan_name(schedule) -> str:
    return schedule.name if schedule is not None else ""


def _run(args, config, plan, sim: bool, completed: set[str], previous_logs: list[str], stack: ExitStack) -> int:
    from bench.logread import read_log
    from bench.progress import ProgressPrinter
    from bench.recorder import McapRecorder
    from bench.report import markdown_report
    from bench.sequencer import Sequencer, SequencerOptions
    from bench.solve_log import solve_logs
    from bench.solver import SolverError
    from drivers.errors import ImuError, TurntableError

    try:
        clock, table, receiver, world = _open_devices(config, sim, stack)
    except (TurntableError, ImuError, ValueError, OSError) as exc:
        return _fail(f"cannot start: {exc}; nothing moved", EXIT_USAGE)
    out_dir = Path(args.out) if args.out else Path(config.output.folder)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        return _fail(f"output folder {out_dir}: {exc}", EXIT_USAGE)
    run_id = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime()) + "-" + secrets.token_hex(3)
    log_path = out_dir / f"{run_id}.mcap"
    recorder = McapRecorder(str(log_path), metadata=_metadata(config, plan, run_id, args, sim, previous_logs))
    stack.callback(recorder.close)
    recorder.add_attachment(config.imu.dbc.name, "text/plain", config.imu.layout.dbc_text.encode())
    for schedule in (config.plan.positions, config.plan.rotations):
        if schedule is not None and Path(schedule.source).is_file():
            recorder.add_attachment(Path(schedule.source).name, "application/toml", Path(schedule.source).read_bytes())
    progress = ProgressPrinter(plan.steps, quiet=args.quiet, simulated=sim)
    options = SequencerOptions(**{"settle_tolerance_deg": config.table.settle_tolerance_deg,
                                  "move_poll_s": config.table.poll_s, **(SIM_OPTIONS if sim else {})})
    sequencer = Sequencer(plan.steps, table, receiver, clock, [recorder, progress], options, completed)
    previous_handler = signal.getsignal(signal.SIGINT)
    signal.signal(signal.SIGINT, lambda *_: sequencer.abort("interrupted (Ctrl-C)"))
    try:
        try:
            table.reset_faults()
            table.enable()
        except TurntableError as exc:
            return _fail(f"cannot enable the table: {exc}; nothing moved", EXIT_FAULT)
        state = sequencer.run()
    finally:
        signal.signal(signal.SIGINT, previous_handler)
        progress.close()
    block = receiver.flush()
    if len(block):
        recorder.on_imu(block)
    if sequencer.error is not None:
        recorder.close()
        print(f"bench run: {state.value}: {sequencer.error}; table stopped. Log: {log_path} "
              f"(continue with --resume {log_path})", file=sys.stderr)
        return EXIT_FAULT
    recorder.flush()
    logs = [read_log(p) for p in previous_logs] + [read_log(str(log_path))]
    identity = config.imu.identity
    gyro_stability, acc_stability = identity.gyro_bias_stability_dph, identity.acc_bias_stability_ug
    if sim and config.sim.noise.enabled:
        # The simulated IMU's bias instability is known: it is what a datasheet would say.
        gyro_stability = gyro_stability if gyro_stability is not None else config.sim.noise.gyro_bias_instability_dph
        acc_stability = acc_stability if acc_stability is not None else config.sim.noise.acc_bias_instability_ug
    try:
        solution = solve_logs(logs, config.site.site, config.imu.layout, config.imu.rate_hz,
                              gyro_bias_stability_dph=gyro_stability, acc_bias_stability_ug=acc_stability,
                              still_open=frozenset({str(log_path)}))
    except SolverError as exc:
        recorder.close()
        return _fail(f"the run finished but cannot be solved: {exc}. Log: {log_path}", EXIT_QUALITY)
    failures = _quality_failures(solution, receiver.stats)
    run_info = {"run_id": run_id, "mode": "simulator" if sim else "hardware", "operator": args.operator,
                "software_version": __version__, "state": state.value, "log": log_path.name,
                "logs": [Path(p).name for p in previous_logs] + [log_path.name],
                "positions": plan_name(config.plan.positions), "rotations": plan_name(config.plan.rotations),
                "finished_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                "imu": {"model": identity.model, "serial": identity.serial},
                "site": config.site.site.to_dict(), "quality_failures": failures,
                "imu_link": receiver.stats.as_dict()}
    result = solution.calibration.to_result(run=run_info, sim_truth=config.sim.imu if sim else None)
    result_path = out_dir / f"{run_id}.result.json"
    result.save(result_path)
    report_path = out_dir / f"{run_id}.report.md"
    report_path.write_text(markdown_report(result, problems=solution.extraction.problems, failures=failures,
                                           imu_link=receiver.stats.as_dict(),
                                           title=f"Calibration report {run_id}"), encoding="utf-8")
    recorder.add_attachment(result_path.name, "application/json", result_path.read_bytes())
    recorder.close()
    if not args.quiet:
        print(f"log:    {log_path}\nresult: {result_path}\nreport: {report_path}")
    if failures:
        print("bench run: quality check failed: " + "; ".join(failures), file=sys.stderr)
        return EXIT_QUALITY
    return EXIT_OK

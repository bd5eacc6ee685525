"""The TUI's layout at the two terminal sizes operators use (100x30 and 140x40): the panels fit.

Issue 19: three blank rows between the top and bottom panels, the Plan panel's "state"
column cut off at 100 columns, the Results panel's truth column cut off (and no
error/sigma), the help screen's text wrapping under the keys. Each test measures the
widgets' regions (what fits) and a snapshot shows the screen; the states are fed straight
into the UI buffer, so both are deterministic.
"""

from __future__ import annotations

import pytest

from tests.helpers.tui import feed_result, feed_running, make_app, run

SIZES = [pytest.param((100, 30), id="100x30"), pytest.param((140, 40), id="140x40")]


def _app(tmp_path):
    # (the session's clocks stand still: the IMU values never turn stale while a snapshot is taken)
    return make_app(tmp_path, auto_connect=False, refresh_hz=10.0, clock=lambda: 0.0,
                    wall_clock=lambda: 1_795_773_600.0)


def _fits(table) -> bool:
    """Every column of a DataTable is visible without scrolling sideways."""
    return table.virtual_size.width <= table.scrollable_content_region.width


async def _fed(pilot, result: bool = False) -> None:
    app = pilot.app
    feed_running(app)
    if result:
        feed_result(app)
    app.refresh_panels()
    await pilot.pause(0.2)


@pytest.mark.parametrize("size", SIZES)
def test_top_and_bottom_panels_touch_and_the_plan_table_fits(tmp_path, size):
    async def body():
        app = _app(tmp_path)
        async with app.run_test(size=size) as pilot:
            await _fed(pilot)
            top, bottom = app.query_one("#top").region, app.query_one("#bottom").region
            tallest = max(app.query_one(name).outer_size.height for name in ("#table-panel", "#imu-panel"))
            assert top.height == tallest and bottom.y == top.bottom, (top, bottom, tallest)
            plan = app.query_one("#plan-steps")
            assert _fits(plan), (plan.virtual_size, plan.scrollable_content_region)
            assert "state" in [str(c.label) for c in plan.columns.values()]
    run(body)


@pytest.mark.slow
@pytest.mark.parametrize("size", SIZES)
def test_results_show_truth_and_error_in_sigmas_without_scrolling(tmp_path, size):
    async def body():
        app = _app(tmp_path)
        async with app.run_test(size=size) as pilot:
            await _fed(pilot, result=True)
            assert app.query_one("#left-tabs").active == "results-tab"
            table = app.query_one("#results-table")
            assert [str(c.label) for c in table.columns.values()] == ["name", "value", "1-sigma", "sim truth",
                                                                      "err/σ"]
            assert _fits(table), (table.virtual_size, table.scrollable_content_region)
            plain = app.query_one("#results-panel").plain
            truth = app.session.config.sim.imu.to_canonical()
            # feed_result puts Kg_y 1.3 sigma below its truth and Kg_z 2.6 sigma above
            sigma = {name: (abs(v) * 1e-6 if abs(v) > 1 else 1e-6) for name, v in truth.items()}   # feed_result's
            for name, z in (("Kg_y", "-1.3"), ("Kg_z", "+2.6"), ("D0_x", "+0.0")):   # to a tenth of a sigma
                value = truth[name] + float(z) * sigma[name]
                assert f"{name} {value:.8g} {sigma[name]:.3g} {truth[name]:.8g} {z}" in plain, plain
            assert "units: Kg counts/s per deg/s, D0 deg/h, Eg Ea 1 (direction cosines), Ka counts/s per g" in plain
            units = app.query_one("#results-units")
            assert units.region.right <= app.query_one("#left-tabs").region.right
    run(body)


@pytest.mark.slow
@pytest.mark.parametrize("size", SIZES)
def test_help_rows_fit_with_descriptions_wrapping_under_themselves(tmp_path, size):
    async def body():
        app = _app(tmp_path)
        async with app.run_test(size=size) as pilot:
            await pilot.pause(0.1)
            app.action_help()
            await pilot.pause(0.2)
            dialog = app.screen.query_one("Vertical")
            assert app.screen.region.contains_region(dialog.region)
            assert dialog.virtual_size.height <= dialog.scrollable_content_region.height   # nothing scrolled away
            help_text = app.screen.query_one("#help-text")
            width = help_text.content_region.width
            strips = help_text.render_lines(help_text.content_region.reset_offset)
            rows = ["".join(seg.text for seg in strip) for strip in strips]
            rows = [r for r in rows if r.strip()]
            # one row per key, plus one continuation of the long F12 text, indented under its description
            assert len(rows) == len(app.screen.keys) + 1, rows
            assert rows[1].startswith(" " * 5) and rows[1].strip().startswith("(servos off)"), rows
            assert all(len(r.rstrip()) <= width for r in rows)
    run(body)


# -- snapshots at both sizes (look at them: tests/__snapshots__/test_tui_layout/) ---------------------

@pytest.mark.slow
@pytest.mark.parametrize("size", SIZES)
def test_snapshot_running_at(tmp_path, snap_compare, size):
    async def before(pilot):
        await _fed(pilot)
    assert snap_compare(_app(tmp_path), terminal_size=size, run_before=before)


@pytest.mark.slow
@pytest.mark.parametrize("size", SIZES)
def test_snapshot_results_at(tmp_path, snap_compare, size):
    async def before(pilot):
        await _fed(pilot, result=True)
    assert snap_compare(_app(tmp_path), terminal_size=size, run_before=before)


@pytest.mark.slow
@pytest.mark.parametrize("size", SIZES)
def test_snapshot_help_at(tmp_path, snap_compare, size):
    async def before(pilot):
        await _fed(pilot)
        pilot.app.action_help()
        await pilot.pause(0.2)
    assert snap_compare(_app(tmp_path), terminal_size=size, run_before=before)


# -- the uncertainty budget (issue 15): the Results status warns, the Budget tab has every coefficient's budget --

@pytest.mark.slow
def test_budget_tab_shows_sigma_u_largest_parts_flags_and_the_highlighted_budget(tmp_path):
    from tests.helpers.tui import feed_budget_result

    async def body():
        app = _app(tmp_path)
        async with app.run_test(size=(100, 30)) as pilot:
            await _fed(pilot, result=True)          # no budget (a version 1 result): the tab says so
            assert app.query_one("#budget-panel").plain.startswith("no uncertainty budget")
            feed_budget_result(app, table_included=False)
            app.refresh_panels()
            await pilot.pause(0.2)
            status = app.query_one("#results-panel").plain.splitlines()[1]
            assert status == "WARNING: turntable pointing NOT in sigma; UNEXPLAINED SCATTER: gyros x (Budget tab)"
            app.query_one("#left-tabs").active = "budget-tab"
            await pilot.pause(0.2)
            panel, table = app.query_one("#budget-panel"), app.query_one("#budget-table")
            assert [str(c.label) for c in table.columns.values()] == ["name", "sigma", "U", "largest part", "next"]
            assert _fits(table), (table.virtual_size, table.scrollable_content_region)
            lines = panel.plain.splitlines()
            assert lines[0].startswith("WARNING: turntable pointing NOT included: sigma and U cover the IMU alone")
            assert lines[1] == ("UNEXPLAINED SCATTER: gyros x residuals (chi2/dof 5, driven by R03 (+5.2), "
                                "R07 (-3.1)): widened x2.5")
            kg_x = app.buffer.snapshot().result.coefficients["Kg_x"]      # noise n and bias instability n/2
            assert f"Kg_x {kg_x.sigma:.3g} {2 * kg_x.sigma:.3g} noise 80% bias inst. 20%" in lines
            assert panel.detail == (f"Kg_x: sigma {kg_x.sigma:.3g} = noise (A) {kg_x.budget['noise']:.2g} (80%) + "
                                    f"bias instab. (B) {kg_x.budget['bias instability']:.2g} (20%) "
                                    f"(root-sum-square); U {2 * kg_x.sigma:.3g} (k = 2)")
            table.focus()
            await pilot.press("down")
            await pilot.pause(0.1)
            assert panel.detail.startswith("Kg_y: sigma ")

            feed_budget_result(app, table_included=True)     # a new result: the table's part in, 3x the noise
            app.refresh_panels()
            await pilot.pause(0.2)
            assert app.query_one("#results-panel").plain.splitlines()[1] == \
                "UNEXPLAINED SCATTER: gyros x (Budget tab)"
            lines = panel.plain.splitlines()
            assert lines[0] == "turntable part: datasheet: pointing accuracy 5 arcsec (1-sigma)"
            kg_x = app.buffer.snapshot().result.coefficients["Kg_x"]
            assert f"Kg_x {kg_x.sigma:.3g} {2 * kg_x.sigma:.3g} turntable 88% noise 10%" in lines
            assert panel.detail.startswith("Kg_x: sigma ")
    run(body)

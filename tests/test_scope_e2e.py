"""The scope in a real headless browser (Debian's chromium driven by Playwright): open the page for
a running lockstep session, see the traces advance, change kp and see it applied and marked,
trigger on a reference step, and save a screenshot that is not blank.

Without chromium or Playwright the test skips with a one-line reason; with HILBENCH_REQUIRE_TOOLS=1
(CI) it fails instead. Playwright's own browser download is never used: it drives /usr/bin/chromium.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

CHROMIUM = os.environ.get("HILBENCH_CHROMIUM", "/usr/bin/chromium")
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]


def _missing() -> str | None:
    if not (os.path.exists(CHROMIUM) or shutil.which("chromium")):
        return f"no chromium at {CHROMIUM} (apt-get install chromium)"
    try:
        import playwright.sync_api  # noqa: F401
        import aiohttp  # noqa: F401
    except ImportError as exc:
        return f"the browser test needs Playwright and aiohttp from PyPI ({exc.name} missing)"
    return None


@pytest.fixture
def browser_page(tmp_path: Path):  # type: ignore[no-untyped-def]
    reason = _missing()
    if reason is not None:
        if os.environ.get("HILBENCH_REQUIRE_TOOLS") == "1":
            pytest.fail(f"HILBENCH_REQUIRE_TOOLS=1: {reason}")
        pytest.skip(reason)
    from playwright.sync_api import sync_playwright

    executable = CHROMIUM if os.path.exists(CHROMIUM) else shutil.which("chromium")
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=executable, args=CHROMIUM_ARGS)
        try:
            context = browser.new_context(viewport={"width": 1280, "height": 820})
            page = context.new_page()
            errors: list[str] = []
            page.on("pageerror", lambda exc: errors.append(str(exc)))
            yield page, errors
        finally:
            browser.close()


def _not_blank(png: Path) -> float:
    """The spread of the screenshot's pixel values (a blank page has none)."""
    import matplotlib.image

    pixels = matplotlib.image.imread(str(png))
    return float(pixels[..., :3].std())


def _leave(page) -> None:  # type: ignore[no-untyped-def]
    """The page goes away before its server stops (as a closed tab would): its websocket closes, so
    ScopeServer.close returns at once instead of waiting out its 5 s join on a page still connected."""
    page.goto("about:blank")


@pytest.mark.slow
def test_scope_page_in_headless_chromium(browser_page, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    from _scope_session import running_session
    from hilbench.scope.server import ControlSource, ScopeServer

    page, errors = browser_page
    timeout_ms = 20_000
    with running_session() as path, ScopeServer(ControlSource(path)) as server:
        page.goto(server.url)
        page.wait_for_function("window.scope.frames > 2 && window.scope.selected.includes('speed_rpm')", timeout=timeout_ms)
        t_before = page.evaluate("window.scope.tLatest")
        page.wait_for_function(f"window.scope.tLatest > {t_before} + 0.1", timeout=timeout_ms)  # traces advance
        lanes = page.evaluate("window.scope.selected")
        assert {"speed_rpm", "ref_speed_rpm", "ia_a", "hall_a", "hall_b", "hall_c"} <= set(lanes)

        page.fill("#param-kp", "0.15")  # through the control socket's checked, guarded set
        page.click("#set-kp")
        page.wait_for_function("document.getElementById('result-kp').textContent.includes('applied at t=')", timeout=timeout_ms)
        page.wait_for_function("window.scope.markers.some(m => m[1] === 'param' && m[2].includes('kp=0.15'))", timeout=timeout_ms)
        page.wait_for_function("Math.abs(parseFloat(document.getElementById('now-kp').textContent) - 0.15) < 1e-3", timeout=timeout_ms)

        page.select_option("#trig-source", "ref")
        page.click("#trig-arm")
        page.fill("#ref-input", "2500")
        page.click("#ref-set")
        page.wait_for_function("window.scope.trigger.state === 'captured'", timeout=timeout_ms)
        t_trigger = page.evaluate("window.scope.captures[0].tTrig")
        ref_marker = page.evaluate("window.scope.markers.find(m => m[2].includes('ref 2500'))")
        assert ref_marker is not None and abs(t_trigger - ref_marker[0]) < 0.01  # the step, not noise
        assert "captured" in page.inner_text("#trig-state")

        shot = tmp_path / "scope.png"
        page.screenshot(path=str(shot))
        _leave(page)
    assert shot.stat().st_size > 10_000 and _not_blank(shot) > 0.05
    assert not errors, errors


@pytest.mark.slow
def test_recording_in_the_same_viewer(browser_page, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    import hilbench
    from hilbench.scope.server import RecordingSource, ScopeServer

    with hilbench.Bench(target="inprocess:an1017", record=tmp_path / "run.npz") as bench:
        bench.set_reference(1500)
        bench.press("s2")
        bench.run(0.4)
        bench.set_params(kp=0.2)
        bench.set_reference(2000)
        bench.run(0.4)
    page, errors = browser_page
    with ScopeServer(RecordingSource(tmp_path / "run.npz")) as server:
        page.goto(server.url)
        page.wait_for_function("window.scope.frames >= 1 && window.scope.data.has('speed_rpm')", timeout=20_000)
        assert page.evaluate("window.scope.meta.live") is False
        assert page.is_hidden("#params")  # nothing to steer in a recording
        assert abs(page.evaluate("window.scope.tLatest") - 0.8) < 1e-3
        assert page.evaluate("window.scope.markers.some(m => m[1] === 'param' && m[2] === 'set kp=0.2')")
        page.select_option("#window", "0.2")  # a 0.2 s view ending at 0.5 s (as a drag would pan it)
        page.evaluate("window.scope.viewEnd = 0.5; window.scopeRedraw()")
        page.wait_for_function("window.scope.view && Math.abs(window.scope.view.ta - 0.3) < 1e-6", timeout=10_000)
        page.click("#trig-arm")  # on a recording: the first reference step after the view's start
        page.wait_for_function("window.scope.trigger.state === 'captured'", timeout=10_000)
        assert abs(page.evaluate("window.scope.captures[0].tTrig") - 0.4) < 0.01
        shot = tmp_path / "recording.png"
        page.screenshot(path=str(shot))
        _leave(page)
    assert _not_blank(shot) > 0.05
    assert not errors, errors


@pytest.mark.slow
def test_live_tuning_on_a_run_without_a_recording(browser_page, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """Issue 22: on a run that keeps no rows (`hilbench run` without --record) the page draws traces;
    speed and reference share a lane; a falling level trigger on the speed captures a step down;
    the parameter boxes and sliders start at the firmware's values; two gains written together are
    one atomic set; the guard's revert after an overcurrent trip is shown beside the gains."""
    from _scope_session import running_session
    from hilbench.scope.server import ControlSource, ScopeServer

    page, errors = browser_page
    timeout_ms = 30_000
    with running_session(keep_rows=False) as path, ScopeServer(ControlSource(path)) as server:
        page.goto(server.url)
        page.wait_for_function("window.scope.frames > 2 && (window.scope.data.get('speed_rpm') || []).length > 0", timeout=timeout_ms)
        t_before = page.evaluate("window.scope.tLatest")
        page.wait_for_function(f"window.scope.tLatest > {t_before} + 0.1", timeout=timeout_ms)  # traces advance
        drawn = page.evaluate("""(() => { const segs = window.scope.data.get('speed_rpm');
            let hi = -Infinity; for (const s of segs) for (const v of s.hi) hi = Math.max(hi, v); return hi; })()""")
        assert 1000 < drawn < 2000  # the motor at 1500 rpm, drawn from the window of rows

        # speed and reference in one lane by default; any trace can join another's lane
        page.wait_for_function("(window.scope.lanes || []).some(l => l.names.includes('speed_rpm') && l.names.includes('ref_speed_rpm'))",
                               timeout=timeout_ms)
        page.select_option("#lane-ic_a", "ia_a")
        page.wait_for_function("window.scope.lanes.some(l => l.names.join() === 'ia_a,ic_a')", timeout=timeout_ms)

        # the boxes and sliders start at the values the firmware holds (kp 0.1, ki 0.01 in Q15)
        page.wait_for_function("Math.abs(parseFloat(document.getElementById('param-kp').value) - 0.1) < 1e-3", timeout=timeout_ms)
        assert abs(float(page.input_value("#slider-kp")) - 0.1) < 2e-3
        assert abs(float(page.input_value("#param-ki")) - 0.01) < 1e-4

        # a level trigger on the speed, falling through 1000 rpm, captures the step down to 500 rpm
        page.select_option("#window", "0.5")
        page.select_option("#trig-source", "level")
        page.select_option("#trig-col", "speed_rpm")
        page.select_option("#trig-edge", "falling")
        page.fill("#trig-level", "1000")
        page.fill("#trig-hyst", "50")
        page.click("#trig-arm")
        page.fill("#ref-input", "500")
        page.click("#ref-set")
        page.wait_for_function("window.scope.trigger.state === 'captured'", timeout=timeout_ms)
        t_trigger = page.evaluate("window.scope.captures[0].tTrig")
        ref_marker = page.evaluate("window.scope.markers.find(m => m[2].includes('ref 500'))")
        assert ref_marker is not None and ref_marker[0] < t_trigger < ref_marker[0] + 0.5  # the speed falls after the step
        around = page.evaluate("""(() => { const c = window.scope.captures[0], segs = c.data.get('speed_rpm');
            const at = (t) => { for (const s of segs) { const i = Math.floor((t - s.t0) / s.dt + 0.5); if (i >= 0 && i < s.n) return [s.lo[i], s.hi[i]]; } return null; };
            return [at(c.tTrig - 0.002), at(c.tTrig)]; })()""")  # the buckets starting there (t0 + i*dt, rounded)
        assert around[0][0] > 1000 and around[1][0] <= 1000  # above the level just before, through it at the trigger
        assert "falling" in page.inner_text("#trig-state") or "captured" in page.inner_text("#trig-state")

        # two gains written together: one atomic set (one event naming both)
        page.fill("#param-kp", "0.05")
        page.fill("#param-ki", "0.9")
        page.click("#set-together")
        page.wait_for_function("document.getElementById('result-together').textContent.includes('applied at t=')", timeout=timeout_ms)
        page.wait_for_function("window.scope.markers.some(m => m[1] === 'param' && m[2] === 'set kp=0.05 ki=0.9')", timeout=timeout_ms)

        # those gains trip the board's comparator (at once, or at the next reference): the guard restores
        # the previous ones and the page says so beside them, with the fault by name
        page.fill("#ref-input", "-2000")
        page.click("#ref-set")
        page.wait_for_function("document.getElementById('result-kp').className.includes('guard')", timeout=timeout_ms)
        assert "overcurrent" in page.inner_text("#result-kp") and "reverted by the guard" in page.inner_text("#result-ki")
        page.wait_for_function("Math.abs(parseFloat(document.getElementById('now-kp').textContent) - 0.1) < 1e-3", timeout=timeout_ms)
        page.wait_for_function("document.getElementById('st-fault').textContent === 'OVERCURRENT'", timeout=timeout_ms)
        assert "bad" in page.get_attribute("#st-fault", "class")
        shot = Path(os.environ.get("HILBENCH_SHOT_DIR", str(tmp_path))) / "tuning.png"
        page.screenshot(path=str(shot))
        _leave(page)
    assert _not_blank(shot) > 0.05
    assert not errors, errors


@pytest.mark.slow
def test_auto_trigger_and_what_the_page_cannot_show(browser_page) -> None:  # type: ignore[no-untyped-def]
    """Auto mode captures without a trigger after a window and re-arms; a page with no trace chosen
    says so on the canvas instead of staying blank."""
    from _scope_session import running_session
    from hilbench.scope.server import ControlSource, ScopeServer

    page, errors = browser_page
    with running_session(keep_rows=False) as path, ScopeServer(ControlSource(path)) as server:
        page.goto(server.url)
        page.wait_for_function("window.scope.frames > 2", timeout=30_000)
        assert page.evaluate("window.scope.notice") == ""
        page.select_option("#window", "0.1")
        page.select_option("#trig-source", "level")
        page.fill("#trig-level", "100000")  # never reached
        page.select_option("#trig-mode", "auto")
        page.click("#trig-arm")
        page.wait_for_function("window.scope.captures.length >= 2", timeout=30_000)  # free captures, re-armed
        assert "auto: no trigger within 0.1 s" in page.inner_text("#trig-state")
        assert page.evaluate("window.scope.trigger.state") in ("armed", "triggered")
        for box in page.query_selector_all("#cols input:checked"):
            box.uncheck()
        page.wait_for_function("window.scope.notice.startsWith('no trace chosen')", timeout=30_000)
        _leave(page)
    assert not errors, errors

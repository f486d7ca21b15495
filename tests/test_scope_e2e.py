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
    assert shot.stat().st_size > 10_000 and _not_blank(shot) > 0.05
    assert not errors, errors

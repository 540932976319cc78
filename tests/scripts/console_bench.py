"""The operator console's speed in a real browser (Debian's Chromium through chromedriver), for
`cargo bench -p baton-tests --bench console`.

Usage: console_bench.py URL STEPS COUNT
  Before the page loads, a script of the test's own watches the DOM: when the chart holds STEPS steps (the first
  render, in ms since the page's navigation began, and by the wall clock), and, by the wall clock (Date.now(), Unix ms), when each step is
  first shown active. Prints one JSON line once COUNT steps were seen active: {"first_render_ms", "rendered_at", "seen":
  {step: unix_ms}}. The waits are Selenium's explicit waits on what the script recorded.
"""

import json
import sys

from selenium.webdriver.support.ui import WebDriverWait

# The same Chromium, flags and driver as the console's browser tests (this folder is on the path).
from console_browser import browser

WATCH = """
window.__seen = {};
window.__firstRender = null;
new MutationObserver(() => {
    const steps = document.querySelectorAll("#chart svg g.step");
    if (window.__firstRender === null && steps.length >= %d) {
        window.__firstRender = performance.now();
        window.__renderedAt = Date.now();
    }
    const now = Date.now();
    for (const g of document.querySelectorAll("#chart svg g.step.active")) {
        if (!(g.dataset.step in window.__seen)) window.__seen[g.dataset.step] = now;
    }
}).observe(document, { subtree: true, childList: true, attributes: true, attributeFilter: ["class"] });
"""


def main():
    url, steps, count = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    driver = browser()
    try:
        driver.execute_cdp_cmd("Page.addScriptToEvaluateOnNewDocument", {"source": WATCH % steps})
        driver.get(url)
        wait = WebDriverWait(driver, 120, poll_frequency=0.2)
        wait.until(lambda d: d.execute_script("return window.__firstRender") is not None)
        wait.until(lambda d: d.execute_script("return Object.keys(window.__seen).length") >= count)
        print(json.dumps({
            "first_render_ms": driver.execute_script("return window.__firstRender"),
            "rendered_at": driver.execute_script("return window.__renderedAt"),
            "seen": driver.execute_script("return window.__seen"),
        }), flush=True)
    finally:
        driver.quit()


if __name__ == "__main__":
    main()

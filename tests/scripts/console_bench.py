"""The operator console's speed in a real browser (Debian's Chromium through chromedriver), for
`cargo bench -p baton-tests --bench console`.

Usage: console_bench.py URL STEPS COUNT
  Before the page loads, a script of the test's own watches the DOM: when the chart holds STEPS steps (the first
  render, in ms since the page's navigation began, and by the wall clock), and, by the wall clock (Date.now(), Unix ms), when each step is
  first shown active. Prints one JSON line once COUNT steps were seen active: {"first_render_ms", "rendered_at", "seen":
  {step: unix_ms}}. The waits are Selenium's explicit waits on what the script recorded.
"""

import json
import os
import sys

from selenium import webdriver
from selenium.webdriver.chrome.service import Service
from selenium.webdriver.support.ui import WebDriverWait

os.environ["SE_OFFLINE"] = "true"

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
    options = webdriver.ChromeOptions()
    options.binary_location = "/usr/bin/chromium"
    for flag in ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync",
                 "--window-size=1400,1000"]:
        options.add_argument(flag)
    driver = webdriver.Chrome(service=Service(executable_path="/usr/bin/chromedriver"), options=options)
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

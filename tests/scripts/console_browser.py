"""Drives Debian's Chromium through its WebDriver (chromedriver, with Selenium's Python bindings) on the page of
`baton console`, as an operator would: reads the chart and the run's state off the page, and clicks a command.

Usage: console_browser.py URL hold STEP COMMAND STATE SCREENSHOT
  waits until the chart shows step STEP active, prints what the page shows (one JSON line `shown`), clicks the
  step and prints why it waits (`why`, `where`), clicks the button of COMMAND, waits until the page shows the
  run in STATE, prints it again (`after`), and saves a screenshot.
Usage: console_browser.py URL ack COMMENT SHELVE_REASON
  waits for an unacknowledged alarm, prints it (`alarm`, `shown_state`); shelves it for 10 minutes with
  SHELVE_REASON as the reason and prints where the page lists it then (`shelved`); unshelves it; writes COMMENT as
  the reason, clicks its ack and waits until the page shows it acknowledged (`reply`).
Usage: console_browser.py URL confirm TRANSITION STEP
  clicks the mode `step` and waits for it (`mode`), sets the input `go` to TRUE in the inputs form, waits until
  TRANSITION waits for a confirmation and prints the
  transitions the chart marks waiting (`waiting`), clicks its confirm and waits until STEP is active (`after`).
Usage: console_browser.py URL manual TRANSITION FIND TO REASON
  clicks the mode `manual`, picks TRANSITION and clicks force with no reason (`refused`: what the page says), writes
  REASON and forces it; finds the step FIND by a part of its name in the search box (`found`, and whether the view
  zoomed to it), moves its token to step TO, waits until TO is active, and prints the commands the history lists
  (`history`).
Usage: console_browser.py URL demo SCREENSHOT COMMENT
  on the demo cell: waits until both picks are active and prints what the page shows (`shown`); clicks hold and
  prints each state the page showed until held (`states`) and the buttons then (`held`); clicks unhold; waits for
  the overrun alarm, acknowledges it with COMMENT (`alarm`); saves SCREENSHOT; prints `kill robot1` and waits until
  the page shows robot1 lost (`lost`).
Usage: console_browser.py URL macro NAME INNER
  waits until the chart's macro step NAME is lit, prints the chart's steps and the lit ones (`chart`, with the
  macro step's agent), clicks it, and prints the steps of its body and the lit ones there (`body`, with the panel's
  title, and where the step panel says the clicked macro step is); then clicks the macro step INNER in that body and
  prints its body (`body`) the same way.
Usage: console_browser.py URL login USER PASSWORD
  logs in through the page's form, waits until the run is shown, and prints the command buttons the user sees
  (`visible`), the header's name (`who`) and the manual mode button's state (`manual`).
Usage: console_browser.py URL timeline STEPS RECORDING SCREENSHOT
  in a browser with WebGL (SwiftShader): waits until the page's Rerun timeline is ready with a recording open
  (`viewer`: backend, recording id, active timeline, time range), clicks the oldest history entry and waits until
  the viewer's time cursor is at its time (`sought`); clicks Rerun's viewer down its chart view and across its
  steps view, and prints each event the viewer sent and what the chart then selected (`clicked`; STEPS: the
  chart's steps in its order, comma-separated); saves SCREENSHOT of the timeline; opens RECORDING from the page's
  recordings list and waits until the viewer has it open (`recording`); prints every origin the page and its frame
  fetched from (`origins`).
Usage: console_browser.py URL nested ACTION
  clicks the block of ACTION (an action written in SFC) on the chart, and prints the steps of the chart it opens
  (`steps`) and each set of them lit seen until every step was lit at least once (`lit`).
Each wait is Selenium's explicit wait on the page's DOM (woken by polling the DOM, not by a fixed sleep).
"""

import json
import os
import sys

from selenium import webdriver
from selenium.common.exceptions import TimeoutException
from selenium.webdriver.chrome.service import Service
from selenium.webdriver.common.action_chains import ActionChains
from selenium.webdriver.common.by import By
from selenium.webdriver.support.ui import Select, WebDriverWait

os.environ["SE_OFFLINE"] = "true"  # never download a driver or a browser: use the machine's


def shown(driver):
    """What an operator reads: the run's state, the lit steps, which buttons are enabled (read in one go in the
    page, so that an update between two reads cannot mix two states)."""
    return driver.execute_script("""
        const steps = [...document.querySelectorAll("#chart svg g.step")];
        const buttons = [...document.querySelectorAll("#commands button")];
        return {
            state: document.getElementById("state").dataset.state,
            active: steps.filter(g => g.classList.contains("active")).map(g => g.dataset.step).sort(),
            agents: steps.filter(g => g.dataset.agent).map(g => g.dataset.step + "@" + g.dataset.agent).sort(),
            all_steps: steps.map(g => g.dataset.step).sort(),
            enabled: buttons.filter(b => !b.disabled).map(b => b.dataset.command).sort(),
            disabled: buttons.filter(b => b.disabled).map(b => b.dataset.command).sort(),
            stale: document.body.classList.contains("stale"),
        };
    """)


def browser(gl=False):
    """Headless Chromium; with `gl`, WebGL 2 drawn in software (SwiftShader), as Rerun's viewer needs it; without,
    no GPU at all, as on a machine without graphics: the console's timeline then says so."""
    options = webdriver.ChromeOptions()
    options.binary_location = "/usr/bin/chromium"
    graphics = ["--enable-unsafe-swiftshader", "--use-angle=swiftshader"] if gl else ["--disable-gpu"]
    for flag in ["--headless", "--no-sandbox", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync",
                 "--window-size=1400,1000"] + graphics:
        options.add_argument(flag)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    return webdriver.Chrome(service=Service(executable_path="/usr/bin/chromedriver"), options=options)


def hold(driver, wait, step, command, state, screenshot):
    wait.until(lambda d: d.find_elements(By.CSS_SELECTOR, f'#chart svg g.step.active[data-step="{step}"]'))
    print(json.dumps({"shown": shown(driver)}), flush=True)
    # The operator clicks the step: the panel says why it waits, as `baton status --why` does.
    driver.find_element(By.CSS_SELECTOR, f'#chart svg g.step[data-step="{step}"]').click()
    wait.until(lambda d: d.find_elements(By.CSS_SELECTOR, "#why li.why"))
    why = [li.text for li in driver.find_elements(By.CSS_SELECTOR, "#why li.why")]
    print(json.dumps({"why": why, "where": driver.find_element(By.ID, "step-where").text}), flush=True)
    driver.find_element(By.CSS_SELECTOR, f'#commands button[data-command="{command}"]').click()
    wait.until(lambda d: d.find_element(By.ID, "state").get_attribute("data-state") == state)
    print(json.dumps({"after": shown(driver), "reply": driver.find_element(By.ID, "reply").text}), flush=True)
    driver.save_screenshot(screenshot)


def ack(driver, wait, comment, shelve_reason):
    """Waits for an unacknowledged alarm; shelves it for 10 minutes with SHELVE_REASON and waits until it is listed
    shelved; unshelves it and waits until it is back in the active list; then writes the comment, clicks its ack,
    and waits until it is acknowledged."""
    row = '#alarms tr[data-state="active_unacknowledged"]'
    wait.until(lambda d: d.find_elements(By.CSS_SELECTOR, row))
    alarm = driver.find_element(By.CSS_SELECTOR, row).get_attribute("data-alarm")
    state = driver.find_element(By.CSS_SELECTOR, row + " .alarm-state").text
    print(json.dumps({"alarm": alarm, "shown_state": state}), flush=True)
    kinds = f"return [...document.querySelectorAll('#alarms tr[data-alarm=\"{alarm}\"]')].map(r => r.dataset.key)"
    reason = driver.find_element(By.ID, "reason")
    reason.send_keys(shelve_reason)
    minutes = driver.find_element(By.ID, "shelve-minutes")
    minutes.clear()
    minutes.send_keys("10")
    driver.find_element(By.CSS_SELECTOR, row + ' button[data-alarm-command="shelve"]').click()
    wait.until(lambda d: d.execute_script(kinds) == [f"shelved:{alarm}"])
    print(json.dumps({"shelved": driver.execute_script(kinds)}), flush=True)
    driver.find_element(By.CSS_SELECTOR, f'#alarms tr[data-key="shelved:{alarm}"] button[data-alarm-command="unshelve"]').click()
    wait.until(lambda d: d.execute_script(kinds) == [f"active:{alarm}"])
    reason.clear()
    reason.send_keys(comment)
    driver.find_element(By.CSS_SELECTOR, row + ' button[data-alarm-command="ack"]').click()
    states = f"return [...document.querySelectorAll('#alarms tr[data-alarm=\"{alarm}\"]')].map(r => r.dataset.state)"
    wait.until(lambda d: "active_unacknowledged" not in d.execute_script(states))
    print(json.dumps({"reply": driver.find_element(By.ID, "reply").text}), flush=True)


def confirm(driver, wait, transition, step):
    """Switches the run to step mode, waits until TRANSITION waits for a confirmation (marked on the chart and
    offered as a button), confirms it, and waits until STEP is active."""
    step_mode = '#modes button[data-mode="step"]'
    wait.until(lambda d: any(b.is_enabled() for b in d.find_elements(By.CSS_SELECTOR, step_mode)))
    driver.find_element(By.CSS_SELECTOR, step_mode).click()
    wait.until(lambda d: d.find_element(By.ID, "mode").get_attribute("data-mode") == "step")
    print(json.dumps({"mode": "step"}), flush=True)
    # The part goes: the operator sets the input `go` in the inputs form.
    wait.until(lambda d: d.find_elements(By.CSS_SELECTOR, '#input-name option[value="go"]'))
    Select(driver.find_element(By.ID, "input-name")).select_by_value("go")
    driver.find_element(By.ID, "input-value").send_keys("TRUE")
    driver.find_element(By.ID, "input-set").click()
    button = f'#waiting button[data-confirm="{transition}"]'
    wait.until(lambda d: d.find_elements(By.CSS_SELECTOR, button))
    marked = driver.execute_script(
        "return [...document.querySelectorAll('#chart svg g.transition.waiting')].map(g => g.dataset.transition)")
    print(json.dumps({"waiting": marked}), flush=True)
    driver.find_element(By.CSS_SELECTOR, button).click()
    wait.until(lambda d: d.find_elements(By.CSS_SELECTOR, f'#chart svg g.step.active[data-step="{step}"]'))
    print(json.dumps({"after": shown(driver)}), flush=True)


def manual(driver, wait, transition, find, to, reason):
    """Manual mode: force a transition, find a step by name and move its token, each with a reason."""
    manual_mode = '#modes button[data-mode="manual"]'
    wait.until(lambda d: any(b.is_enabled() for b in d.find_elements(By.CSS_SELECTOR, manual_mode)))
    driver.find_element(By.CSS_SELECTOR, manual_mode).click()
    wait.until(lambda d: d.find_element(By.ID, "mode").get_attribute("data-mode") == "manual")
    force = 'button[data-manual="force"]'
    wait.until(lambda d: d.find_element(By.CSS_SELECTOR, force).is_enabled())
    Select(driver.find_element(By.ID, "force-transition")).select_by_value(transition)
    driver.find_element(By.CSS_SELECTOR, force).click()
    print(json.dumps({"refused": driver.find_element(By.ID, "reply").text}), flush=True)
    driver.find_element(By.ID, "reason").send_keys(reason)
    driver.find_element(By.CSS_SELECTOR, force).click()
    search = driver.find_element(By.ID, "search")
    search.send_keys(find + "\n")
    wait.until(lambda d: d.find_elements(By.CSS_SELECTOR, "#chart svg g.step.active.found"))
    view = driver.execute_script("""
        const svg = document.querySelector("#chart svg");
        return { width: svg.viewBox.baseVal.width, full: +svg.getAttribute("width") };
    """)
    found = driver.find_element(By.ID, "step-name").text
    print(json.dumps({"found": found, "zoomed": view["width"] < view["full"]}), flush=True)
    Select(driver.find_element(By.ID, "move-to")).select_by_value(to)
    driver.find_element(By.CSS_SELECTOR, 'button[data-manual="move"]').click()
    wait.until(lambda d: d.find_elements(By.CSS_SELECTOR, f'#chart svg g.step.active[data-step="{to}"]'))
    Select(driver.find_element(By.ID, "history-kind")).select_by_value("command")
    rows = "#history tr[data-event='command']"
    wait.until(lambda d: len(d.find_elements(By.CSS_SELECTOR, rows)) >= 3)
    history = [[td.text for td in r.find_elements(By.TAG_NAME, "td")] for r in driver.find_elements(By.CSS_SELECTOR, rows)]
    print(json.dumps({"history": history, "after": shown(driver)}), flush=True)


def demo(driver, wait, screenshot, comment):
    """The demo cell operated from the page, as the issue's operator does it."""
    active = lambda step: f'#chart svg g.step.active[data-step="{step}"]'
    wait.until(lambda d: d.find_elements(By.CSS_SELECTOR, active("Pick1")) and d.find_elements(By.CSS_SELECTOR, active("Pick2")))
    # What the steps' times below their boxes show, sampled from now on: the most each reached, and whether it was
    # marked past its limit.
    driver.execute_script("""
        window.seenTimes = {};
        setInterval(() => {
            for (const t of document.querySelectorAll("#chart svg g.step text.time[data-active-ms]")) {
                const step = t.parentNode.dataset.step;
                const seen = window.seenTimes[step] || { max_ms: 0, over: false, text: "" };
                if (+t.dataset.activeMs >= seen.max_ms) { seen.max_ms = +t.dataset.activeMs; seen.text = t.textContent; }
                seen.over = seen.over || t.classList.contains("over");
                window.seenTimes[step] = seen;
            }
        }, 20);
    """)
    wait.until(lambda d: d.execute_script("return document.body.dataset.timeline") in ("ready", "unavailable"))
    print(json.dumps({"shown": shown(driver), "values": driver.execute_script(
        "return Object.fromEntries([...document.querySelectorAll('#values tr')].map(r => [r.dataset.var, r.cells[1].textContent]))"),
        "timeline": [driver.execute_script("return document.body.dataset.timeline"),
                     driver.find_element(By.ID, "timeline-said").text]}), flush=True)
    # Every state the page shows from the click on, in order.
    driver.execute_script("""
        window.seenStates = [];
        const state = document.getElementById("state");
        new MutationObserver(() => {
            const s = state.dataset.state;
            if (window.seenStates[window.seenStates.length - 1] !== s) window.seenStates.push(s);
        }).observe(state, { attributes: true, attributeFilter: ["data-state"] });
    """)
    driver.find_element(By.CSS_SELECTOR, '#commands button[data-command="hold"]').click()
    wait.until(lambda d: d.find_element(By.ID, "state").get_attribute("data-state") == "held")
    print(json.dumps({"states": driver.execute_script("return window.seenStates"), "held": shown(driver)}), flush=True)
    driver.find_element(By.CSS_SELECTOR, '#commands button[data-command="unhold"]').click()
    wait.until(lambda d: d.find_element(By.ID, "state").get_attribute("data-state") == "execute")
    row = '#alarms tr[data-state="active_unacknowledged"]'
    wait.until(lambda d: d.find_elements(By.CSS_SELECTOR, row))
    alarm = driver.find_element(By.CSS_SELECTOR, row)
    seen = [alarm.get_attribute("data-alarm"), alarm.get_attribute("data-source"),
            alarm.find_element(By.CSS_SELECTOR, ".alarm-state").text]
    alarm_id = alarm.get_attribute("data-alarm")
    driver.find_element(By.ID, "reason").send_keys(comment)
    alarm.find_element(By.CSS_SELECTOR, 'button[data-alarm-command="ack"]').click()
    states = f"return [...document.querySelectorAll('#alarms tr[data-alarm=\"{alarm_id}\"]')].map(r => r.dataset.state)"
    wait.until(lambda d: "active_unacknowledged" not in d.execute_script(states))
    print(json.dumps({"alarm": seen, "times": driver.execute_script("return window.seenTimes")}), flush=True)
    rows = "#history tr[data-event='ack']"
    wait.until(lambda d: d.find_elements(By.CSS_SELECTOR, rows))
    driver.save_screenshot(screenshot)
    print(json.dumps({"kill": "robot1"}), flush=True)
    lost = '#agents tr.lost[data-agent="robot1"]'
    wait.until(lambda d: d.find_elements(By.CSS_SELECTOR, lost))
    print(json.dumps({"lost": driver.find_element(By.CSS_SELECTOR, lost).text}), flush=True)


VIEWER = "const frame = document.querySelector('#timeline-frame iframe'); const api = frame.contentWindow.batonViewer;"


def timeline(driver, steps, recording, screenshot):
    """The Rerun timeline in the page: live, driven from the history, and telling the chart what is selected."""
    wait = WebDriverWait(driver, 150, poll_frequency=0.1)  # 40 MB of wasm, compiled and drawn in software
    wait.until(lambda d: d.execute_script("return document.body.dataset.timeline") in ("ready", "unavailable"))
    said = driver.find_element(By.ID, "timeline-said").text
    if driver.execute_script("return document.body.dataset.timeline") != "ready":
        raise AssertionError("the timeline did not start: " + said)
    wait.until(lambda d: d.execute_script(VIEWER + "return api.time()") is not None)
    viewer = driver.execute_script(VIEWER + "return api.describe();")
    print(json.dumps({"viewer": viewer}), flush=True)
    # The oldest history entry: a click moves the viewer's cursor to its time.
    rows = "#history tr"
    wait.until(lambda d: d.find_elements(By.CSS_SELECTOR, rows))
    row = driver.find_elements(By.CSS_SELECTOR, rows)[-1]
    target = float(row.get_attribute("data-unix-ms"))
    row.click()
    wait.until(lambda d: abs(d.execute_script(VIEWER + "return api.time()") - target) < 1)
    print(json.dumps({"sought": {"entry": target, "event": row.get_attribute("data-event"),
                                 "row": "sought" in row.get_attribute("class"),
                                 "viewer": driver.execute_script(VIEWER + "return api.describe();")}}), flush=True)
    print(json.dumps({"clicked": clicked_in_viewer(driver, steps.split(","))}), flush=True)
    driver.execute_script("document.getElementById('timeline').scrollIntoView({block: 'end'})")
    driver.save_screenshot(screenshot)
    if recording:
        item = f'#recordings li[data-recording="{recording}"]'
        wait.until(lambda d: d.find_elements(By.CSS_SELECTOR, item))
        driver.find_element(By.CSS_SELECTOR, item).click()
        wait.until(lambda d: d.execute_script("return document.body.dataset.timeline") == "ready"
                   and d.execute_script(VIEWER + "return api.time()") is not None)
        print(json.dumps({"recording": driver.execute_script(VIEWER + "return api.describe();")}), flush=True)
    # Every origin fetched from, by the page and by the viewer's frame.
    origins = driver.execute_script(VIEWER + """
        const of = w => w.performance.getEntriesByType("resource").map(e => new URL(e.name).origin);
        return [...new Set(of(window).concat(of(frame.contentWindow)).concat([location.origin]))].sort();""")
    print(json.dumps({"origins": origins}), flush=True)


def clicked_in_viewer(driver, steps):
    """Real clicks on Rerun's viewer (its canvas, in the console's frame), as an operator's mouse makes them: down
    the middle of the chart view (the left two fifths of Baton's blueprint, its upper three quarters), then across
    the rows of the steps view (the right three fifths, its upper half), every 2% of the frame's height (a node
    of the graph is about twice that). Before each click another view is clicked, so that every click changes the
    selection and Rerun reports it once. For each click: the event Rerun's viewer sent, and what the page's chart
    selected after it — once it shows the step the event names (a step's timeline `/sfc/steps/STEP`, or a node of
    the chart graph, whose first instances are STEPS in the chart's order), or, if it never does, what it shows
    then."""
    frame = driver.find_element(By.CSS_SELECTOR, "#timeline-frame iframe")
    driver.execute_script("arguments[0].scrollIntoView({block: 'center'})", frame)
    width, height = driver.execute_script(
        "const r = arguments[0].getBoundingClientRect(); return [r.width, r.height]", frame)
    driver.execute_script(VIEWER + """
        window.viewerEvents = [];
        const handle = api.event;
        api.event = json => { window.viewerEvents.push(json); handle(json); };""")
    count = lambda: driver.execute_script("return window.viewerEvents.length")
    quick = WebDriverWait(driver, 10, poll_frequency=0.05)  # a frame or two drawn in software
    page = WebDriverWait(driver, 5, poll_frequency=0.05)  # a message between two frames of one page

    def click(fx, fy):
        """The event Rerun's viewer sent for a click at (fx, fy) of its frame, or None if the click changed
        nothing it reports (a bare part of a bar or a header)."""
        before = count()
        ActionChains(driver).move_to_element_with_offset(frame, int((fx - 0.5) * width), int((fy - 0.5) * height)) \
            .click().perform()
        try:
            quick.until(lambda d: count() > before)
        except TimeoutException:
            return None
        return json.loads(driver.execute_script("return window.viewerEvents[window.viewerEvents.length - 1]"))

    def named(event):
        item = event["items"][0] if event.get("items") else {}
        path = item.get("entity_path", "")
        if path.startswith("/sfc/steps/"):
            return path[len("/sfc/steps/"):]
        if path == "/sfc/graph" and item.get("instance_id", len(steps)) < len(steps):
            return steps[item["instance_id"]]
        return None

    chart_views = lambda: driver.execute_script(
        "return [...document.querySelectorAll('#chart svg g.step.selected')].map(g => g.dataset.step)")
    clicks = []
    scans = [[(0.2, y / 100) for y in range(10, 73, 2)], [(0.85, y / 100) for y in range(10, 39, 2)]]
    for scan, elsewhere in zip(scans, [(0.7, 0.45), (0.03, 0.5)]):
        for (fx, fy) in scan:
            click(*elsewhere)
            event = click(fx, fy)
            step = named(event) if event else None
            if step is not None:
                try:
                    page.until(lambda d: chart_views() == [step])
                except TimeoutException:
                    pass
            clicks.append({"at": [fx, fy], "event": event, "selected": chart_views()})
    return clicks


def nested(driver, wait, action):
    """An action written in SFC, opened as a chart of its own, its token moving."""
    block = f'#chart svg g.action.nested[data-nested="{action}"]'
    wait.until(lambda d: d.find_elements(By.CSS_SELECTOR, block))
    driver.find_element(By.CSS_SELECTOR, block).click()
    wait.until(lambda d: d.find_elements(By.CSS_SELECTOR, "#nested-chart svg g.step"))
    driver.execute_script("""
        window.litSeen = [];
        setInterval(() => {
            const lit = [...document.querySelectorAll("#nested-chart svg g.step.active")].map(g => g.dataset.step).sort();
            const key = JSON.stringify(lit);
            if (!window.litSeen.some(l => JSON.stringify(l) === key)) window.litSeen.push(lit);
        }, 10);
    """)
    steps = driver.execute_script("return [...document.querySelectorAll('#nested-chart svg g.step')].map(g => g.dataset.step)")
    every = lambda d: set(steps) <= {s for lit in d.execute_script("return window.litSeen") for s in lit}
    wait.until(every)
    print(json.dumps({"steps": steps, "lit": driver.execute_script("return window.litSeen"),
                      "title": driver.find_element(By.ID, "nested-name").text}), flush=True)


def macro(driver, wait, name, inner):
    """A macro step of the chart: waits until it is lit, prints the chart's steps and those lit (`chart`), clicks it,
    and prints the steps of the body it opens and those lit there (`body`), with the panel's title; then clicks the
    macro step INNER in that body and prints its body the same way."""
    box = f'#chart svg g.step.macro[data-step="{name}"]'
    wait.until(lambda d: d.find_elements(By.CSS_SELECTOR, box + ".active"))
    steps = "return [...document.querySelectorAll(arguments[0] + ' svg g.step')].map(g => g.dataset.step).sort()"
    lit = "return [...document.querySelectorAll(arguments[0] + ' svg g.step.active')].map(g => g.dataset.step).sort()"
    print(json.dumps({"chart": {"steps": driver.execute_script(steps, "#chart"),
                                "lit": driver.execute_script(lit, "#chart"),
                                "agent": driver.find_element(By.CSS_SELECTOR, box).get_attribute("data-agent")}}), flush=True)
    for click, opened in [(box, name), (f'#nested-chart svg g.step.macro[data-step="{inner}"]', inner)]:
        driver.find_element(By.CSS_SELECTOR, click).click()
        wait.until(lambda d: d.find_element(By.ID, "nested-name").text == opened
                   and d.execute_script(lit, "#nested-chart"))
        print(json.dumps({"body": {"steps": driver.execute_script(steps, "#nested-chart"),
                                   "lit": driver.execute_script(lit, "#nested-chart"),
                                   "title": driver.find_element(By.ID, "nested-kind").text + " "
                                   + driver.find_element(By.ID, "nested-name").text,
                                   "where": driver.find_element(By.ID, "step-where").text}}), flush=True)


def login(driver, wait, user, password):
    """Logs in as USER and says which command buttons the page then shows."""
    wait.until(lambda d: d.find_element(By.ID, "login-user").is_displayed())
    driver.find_element(By.ID, "login-user").send_keys(user)
    driver.find_element(By.ID, "login-password").send_keys(password)
    driver.find_element(By.ID, "login-submit").click()
    wait.until(lambda d: d.find_element(By.ID, "state").get_attribute("data-state"))
    wait.until(lambda d: d.find_elements(By.CSS_SELECTOR, "#chart svg g.step"))
    seen = driver.execute_script("""
        const kinds = ["command", "mode", "confirm", "stepCommand", "manual", "alarmCommand", "agentCommand"];
        const commands = [...document.querySelectorAll("button")]
            .filter(b => kinds.some(k => b.dataset[k] !== undefined) || b.id === "input-set");
        const manual = document.querySelector('#modes button[data-mode="manual"]');
        return {
            visible: commands.filter(b => b.offsetParent !== null).map(b => b.textContent.trim()).sort(),
            who: document.getElementById("who").textContent,
            manual: manual ? { disabled: manual.disabled, title: manual.title } : null,
        };
    """)
    print(json.dumps(seen), flush=True)


def main():
    url, mode = sys.argv[1:3]
    driver = browser(gl=mode == "timeline")
    try:
        run(driver, url, mode)
    except Exception:
        # What the page's script said, for the failure's message.
        for e in driver.get_log("browser"):
            print("browser:", e.get("message"), file=sys.stderr)
        print("the page said:", driver.find_element(By.ID, "reply").text, file=sys.stderr)
        raise
    finally:
        driver.quit()


def run(driver, url, mode):
    driver.get(url)
    wait = WebDriverWait(driver, 30, poll_frequency=0.05)
    if mode == "hold":
        hold(driver, wait, *sys.argv[3:7])
    elif mode == "confirm":
        confirm(driver, wait, *sys.argv[3:5])
    elif mode == "manual":
        manual(driver, wait, *sys.argv[3:7])
    elif mode == "demo":
        demo(driver, wait, *sys.argv[3:5])
    elif mode == "login":
        login(driver, wait, *sys.argv[3:5])
    elif mode == "nested":
        nested(driver, wait, sys.argv[3])
    elif mode == "macro":
        macro(driver, wait, *sys.argv[3:5])
    elif mode == "timeline":
        timeline(driver, *sys.argv[3:6])
    else:
        ack(driver, wait, sys.argv[3], sys.argv[4])
    # The page's script raised nothing meanwhile.
    errors = [e["message"] for e in driver.get_log("browser") if e.get("source") == "javascript"]
    if errors:
        sys.exit("the page's script failed: " + "; ".join(errors))


if __name__ == "__main__":
    main()

"""The HTML report of a real (tiny) campaign, opened in headless Chromium: every image loads, the
page logs no console error or exception, and every table the report lists is on the page.

How the browser is driven, and why: through the Chrome DevTools Protocol over
`--remote-debugging-pipe` (JSON messages separated by NUL bytes on file descriptors 3 and 4), a
protocol Chromium maintains itself, spoken here with the standard library. Playwright would need
its own node driver (a 100 MB package) and, to find a browser it did not download, a path given
by hand; `--dump-dom` with `--enable-logging` gives the page after load but no reliable console
errors (a failed image load is reported to DevTools, not to the log). The test looks for
`chromium-headless-shell`, `chromium`, `chromium-browser`, `google-chrome` (or the executable
named by SEUWGPU_CHROMIUM) on PATH and skips where there is none.
"""

from __future__ import annotations

import json
import os
import re
import select
import shutil
import subprocess
import time
from pathlib import Path

import pandas as pd
import pytest

BROWSERS = ("chromium-headless-shell", "chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


def find_chromium() -> str | None:
    named = os.environ.get("SEUWGPU_CHROMIUM")
    if named:
        return shutil.which(named)
    return next((path for path in map(shutil.which, BROWSERS) if path), None)


class DevTools:
    """One headless Chromium driven over --remote-debugging-pipe; events are kept in `events`."""

    def __init__(self, browser: str, timeout: float = 60):
        self.timeout = timeout
        to_browser_r, self.to_browser = os.pipe()
        self.from_browser, from_browser_w = os.pipe()

        def onto_3_and_4():  # Chromium reads commands on fd 3, writes replies and events on fd 4
            read_end, write_end = os.dup(to_browser_r), os.dup(from_browser_w)  # so dup2 onto 3 closes neither
            os.dup2(read_end, 3)
            os.dup2(write_end, 4)

        self.proc = subprocess.Popen(
            [
                browser,
                "--headless",
                "--no-sandbox",  # as root in a container
                "--disable-gpu",
                "--no-first-run",
                "--remote-debugging-pipe",
                "about:blank",
            ],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            pass_fds=(3, 4),
            preexec_fn=onto_3_and_4,
        )
        os.close(to_browser_r)
        os.close(from_browser_w)
        self.buffer = b""
        self.next_id = 0
        self.events: list[dict] = []
        self.session: str | None = None

    def send(self, method: str, params: dict | None = None, session: bool = True) -> dict:
        self.next_id += 1
        msg = {"id": self.next_id, "method": method, "params": params or {}}
        if session and self.session:
            msg["sessionId"] = self.session
        os.write(self.to_browser, json.dumps(msg).encode() + b"\0")
        while True:
            reply = self.receive()
            if reply.get("id") == self.next_id:
                assert "error" not in reply, f"{method}: {reply['error']}"
                return reply["result"]

    def receive(self) -> dict:
        deadline = time.monotonic() + self.timeout
        while b"\0" not in self.buffer:
            left = deadline - time.monotonic()
            ready, _, _ = select.select([self.from_browser], [], [], max(left, 0))
            assert ready, "Chromium did not answer in time"
            chunk = os.read(self.from_browser, 1 << 16)
            assert chunk, "Chromium closed its DevTools pipe"
            self.buffer += chunk
        raw, self.buffer = self.buffer.split(b"\0", 1)
        msg = json.loads(raw)
        if "method" in msg:
            self.events.append(msg)
        return msg

    def wait_for(self, method: str) -> dict:
        seen = next((e for e in self.events if e["method"] == method), None)
        while seen is None:
            msg = self.receive()
            if msg.get("method") == method:
                seen = msg
        return seen

    def open_page(self, url: str):
        targets = self.send("Target.getTargets", session=False)["targetInfos"]
        page = next(t for t in targets if t["type"] == "page")
        self.session = self.send("Target.attachToTarget", {"targetId": page["targetId"], "flatten": True})["sessionId"]
        for domain in ("Page", "Runtime", "Log"):
            self.send(f"{domain}.enable")
        self.send("Page.navigate", {"url": url})
        self.wait_for("Page.loadEventFired")

    def evaluate(self, expression: str):
        result = self.send("Runtime.evaluate", {"expression": expression, "returnByValue": True, "awaitPromise": True})
        assert "exceptionDetails" not in result, result["exceptionDetails"]
        return result["result"]["value"]

    def errors(self) -> list[str]:
        """Console errors, uncaught exceptions and error log entries (failed loads among them)."""
        found = []
        for e in self.events:
            p = e.get("params", {})
            if e["method"] == "Runtime.consoleAPICalled" and p["type"] in ("error", "assert"):
                found.append("console: " + " ".join(str(a.get("value", a.get("description"))) for a in p["args"]))
            elif e["method"] == "Runtime.exceptionThrown":
                found.append("exception: " + p["exceptionDetails"].get("text", ""))
            elif e["method"] == "Log.entryAdded" and p["entry"]["level"] == "error":
                found.append(f"log ({p['entry']['source']}): {p['entry']['text']} {p['entry'].get('url', '')}")
        return found

    def close(self):
        try:
            self.send("Browser.close", session=False)
        except (AssertionError, OSError):
            pass
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        os.close(self.to_browser)
        os.close(self.from_browser)


# what the page holds, read by the browser after load
PAGE_STATE = """(() => {
  const images = [...document.images].map(i => ({alt: i.alt, complete: i.complete, width: i.naturalWidth}));
  const tables = [...document.querySelectorAll('h3')].map(h => {
    const body = h.nextElementSibling && h.nextElementSibling.nextElementSibling;
    return {title: h.textContent, tag: body ? body.tagName : null,
            note: body && body.classList.contains('note'),
            rows: body && body.tagName === 'TABLE' ? body.tBodies[0].rows.length : 0};
  });
  const sections = [...document.querySelectorAll('h2[id]')].map(h => h.id);
  const headings = [...document.querySelectorAll('h2')].map(h => h.id || h.textContent);
  const summary = document.getElementById('summary');
  let first = [];  // what the summary section holds, up to the next heading
  for (let e = summary && summary.nextElementSibling; e && e.tagName !== 'H2'; e = e.nextElementSibling) {
    first.push(e.tagName === 'FIGURE' ? 'FIGURE:' + e.querySelector('img').alt : e.tagName);
  }
  return {images, tables, sections, headings, summary: first, title: document.title};
})()"""


@pytest.fixture(scope="module")
def browser() -> str:
    """Chromium's executable; the test skips (before making its report) where there is none."""
    found = find_chromium()
    if found is None:
        pytest.skip(f"no Chromium on PATH ({', '.join(BROWSERS)}; or SEUWGPU_CHROMIUM)")
    return found


@pytest.fixture(scope="module")
def report(tmp_path_factory) -> Path:
    """The report of a tiny campaign on the spheres scene: two fields, three bits, two defenses."""
    from seuwgpu.campaign.runner import Runner
    from seuwgpu.campaign.spec import normalize_spec
    from seuwgpu.report.build import build_report

    tmp = tmp_path_factory.mktemp("browser")
    spec = normalize_spec(
        {
            "views": 1,
            "size": "16x16",
            "scenes": [{"scene": "spheres", "n": 200}],
            "single": {
                "fields": ["opacity", "log_scales"],
                "bits": [0, 30, 31],
                "samples": 4,
                "defenses": ["none", "guard"],
            },
        }
    )
    Runner(spec, tmp / "run", quiet=True).run()
    return build_report([tmp / "run"], tmp / "report")


def page_state(browser: str, uri: str) -> tuple[dict, list[str]]:
    """(PAGE_STATE of the page at `uri`, what the browser reported against it) in a fresh tab."""
    tools = DevTools(browser)
    try:
        tools.open_page(uri)
        return tools.evaluate(PAGE_STATE), tools.errors()
    finally:
        tools.close()


def test_the_browser_check_sees_a_broken_image_and_console_errors(browser, tmp_path):
    """The report test passes only if this harness reports what breaks a page: without this, a
    Chromium that stopped sending those events would let any report through."""
    page = tmp_path / "broken.html"
    page.write_text(
        "<html><body><img alt='gone' src='missing.png'>"
        "<script>console.error('boom')</script><script>throw new Error('uncaught')</script></body></html>"
    )
    state, errors = page_state(browser, page.as_uri())
    assert state["images"] == [{"alt": "gone", "complete": True, "width": 0}]
    assert any(e.startswith("log (network):") and "missing.png" in e for e in errors), errors
    assert "console: boom" in errors, errors
    assert any(e.startswith("exception:") for e in errors), errors


@pytest.mark.slow  # it runs a campaign and builds its report first
def test_the_report_in_headless_chromium(browser, report):
    out = report.parent
    source = report.read_text()
    summary = json.loads((out / "summary.json").read_text())
    state, errors = page_state(browser, report.as_uri())

    assert not errors, errors
    # every figure of the report is an image on the page, and each one decoded
    figures = sorted(p.name for p in out.glob("*.png"))
    assert figures and len(state["images"]) == len(figures) == source.count("<img "), (state["images"], figures)
    for image in state["images"]:
        assert image["complete"] and image["width"] > 0, f"image not loaded: {image['alt']}"
    # every section summary.json lists has its heading, and every table its rows (or, for one too
    # long to inline, the note linking its CSV)
    assert state["sections"] == [*summary["sections"], "skipped"]
    assert state["tables"], "no tables on the page"
    for table in state["tables"]:
        assert table["tag"] == "TABLE" and table["rows"] > 0 or table["note"], table
    linked = set(re.findall(r"<a href='([^']+\.csv)'>", source))
    assert len(linked) == len(state["tables"]) and all((out / name).is_file() for name in linked)
    assert any(t["tag"] == "TABLE" for t in state["tables"])


@pytest.mark.slow  # it runs a campaign and builds its report first
def test_the_report_opens_with_the_summary_and_its_worst_flip_panel(browser, report):
    """Issue 45: the page opens with the answer to the user's question (the model, p_c, the most
    dangerous cells, the worst flip's panel, each defense, the cheapest meeting the target), the
    runs and the contents after it, then the claims of the paper."""
    out = report.parent
    state, errors = page_state(browser, report.as_uri())
    assert not errors, errors
    assert state["headings"][:4] == ["summary", "Runs", "Contents", "claims"], state["headings"]
    assert state["summary"][0] == "P"  # the lead: the answer in a few sentences
    assert "FIGURE:The worst flip found" in state["summary"]
    panel = next(i for i in state["images"] if i["alt"] == "The worst flip found")
    assert panel["complete"] and panel["width"] > 0
    titles = [t["title"] for t in state["tables"]]
    for t in ("The model", "p_c: catastrophic probability per upset, no defense", "Each defense measured"):
        assert t in titles
    assert any(t.startswith("The cheapest defense meeting the target") for t in titles)
    models = pd.read_csv(out / "summary_models.csv")
    assert models.iloc[0].to_dict() == {
        "scene": "spheres",
        "primitives": 200,
        "format": "embedded scene",
        "SH degree": 3,
        "precisions": "fp32",
        "what the loader changed": "none",
    }
    # the panel rendered again is the recorded flip: the same footprint as its record
    num = json.loads((out / "summary.json").read_text())["numbers"]["summary"]
    caption = (out / "report.md").read_text()
    assert f"footprint {100 * num['worst']['footprint']:.3g}% without a defense" in caption
    assert all(d["time_ms"] > 0 for d in num["defenses"])  # measured in the run

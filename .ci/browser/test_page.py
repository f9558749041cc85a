#!/usr/bin/env python3
"""Real-browser test of salient's web page: headless Chromium through Playwright (sync API)
against a running server that holds the 7 CAPOD fixtures of tests/fixtures/capod.

    python3 .ci/browser/test_page.py --url URL --key KEY [--screenshots DIR]

(or SALIENT_URL, SALIENT_API_KEY, SALIENT_SCREENSHOTS). `.ci/browser/run` starts the server,
ingests the fixtures and runs this. The checks run in order, each building on the one before;
the first failure stops the run with a message, a screenshot and exit code 1.
"""
import argparse
import os
import pathlib
import re
import shutil
import sys
import time
import urllib.request

from playwright.sync_api import Error as PlaywrightError
from playwright.sync_api import sync_playwright

ROOT = pathlib.Path(__file__).resolve().parents[2]
FIXTURES = ROOT / "tests" / "fixtures"
LIBRARY = ["airplane_m37", "chair_m35", "desktop_computer_m78", "dolphin_m13", "hand_m95",
           "horse_m145", "human_m1"]
# Flags that give headless Chromium a software WebGL (SwiftShader through ANGLE) on a machine
# without a GPU; without --enable-unsafe-swiftshader, recent Chromium refuses (or warns about)
# the software fallback.
CHROMIUM_ARGS = ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                 "--ignore-gpu-blocklist"]
SEARCH_TIMEOUT_MS = 180_000  # an upload is extracted by the server: slow on a busy CI machine
UI_TIMEOUT_MS = 30_000
THUMBS_TIMEOUT_MS = 90_000  # the server renders each thumbnail once


class CheckFailed(Exception):
    pass


def expect(condition, message):
    if not condition:
        raise CheckFailed(message)


# Reads the 3D view's pixels in the page (the canvas keeps its drawing buffer): how many differ
# from the background (the corner pixel), how many distinct colours (4 bits a channel), and how
# much is drawn in the left and right thirds (query and result side by side).
READ_VIEW = """() => {
  const src = document.querySelector('#view');
  const c = document.createElement('canvas');
  c.width = src.width; c.height = src.height;
  const g = c.getContext('2d');
  g.drawImage(src, 0, 0);
  const d = g.getImageData(0, 0, c.width, c.height).data;
  const bg = [d[0], d[1], d[2]];
  let drawn = 0, left = 0, right = 0, red = 0, orange = 0;
  const colours = new Set();
  for (let i = 0; i < d.length; i += 4) {
    const diff = Math.abs(d[i] - bg[0]) + Math.abs(d[i + 1] - bg[1]) + Math.abs(d[i + 2] - bg[2]);
    if (diff <= 24) continue;
    drawn++;
    const x = (i / 4) % c.width;
    if (x < c.width / 3) left++;
    if (x > 2 * c.width / 3) right++;
    if (d[i] > 180 && d[i + 1] < 80 && d[i + 2] < 80) red++;
    // A placed part (view.js PIECE, 0.96 / 0.5 / 0.12, shaded): green half of red, little blue.
    if (d[i] > 80 && d[i + 1] > 0.35 * d[i] && d[i + 1] < 0.7 * d[i] && d[i + 2] < 0.3 * d[i]) orange++;
    colours.add((d[i] >> 4) << 8 | (d[i + 1] >> 4) << 4 | (d[i + 2] >> 4));
  }
  return { width: c.width, height: c.height, drawn, left, right, red, orange, colours: colours.size,
           hash: Array.from(d.filter((_, i) => i % 97 === 0)).join(',') };
}"""

THUMBS_SETTLED = """(sel) => {
  const cards = [...document.querySelectorAll(sel)];
  return cards.length > 0 && cards.every((c) => c.dataset.thumb && c.dataset.thumb !== 'loading'
    && (c.dataset.thumb !== 'loaded' || c.querySelector('img').complete));
}"""

BROKEN_THUMBS = """(sel) => [...document.querySelectorAll(sel)]
  .filter((c) => { const img = c.querySelector('img'); return !img || !img.complete || img.naturalWidth === 0; })
  .map((c) => c.dataset.modelId + ':' + c.dataset.thumb)"""


def horse_part():
    """An OBJ of a piece of the horse fixture: the triangles within 35 % of its size around its
    highest vertex (CAPOD stands on +z), turned a quarter about z, doubled and moved, so that
    the placement the search returns must undo all three."""
    vertices, faces = [], []
    for line in (FIXTURES / "capod" / "horse_m145.obj").read_text().splitlines():
        fields = line.split()
        if fields[:1] == ["v"]:
            vertices.append(tuple(float(x) for x in fields[1:4]))
        elif fields[:1] == ["f"]:
            faces.append([int(f.split("/")[0]) - 1 for f in fields[1:]])
    lo = [min(v[k] for v in vertices) for k in range(3)]
    hi = [max(v[k] for v in vertices) for k in range(3)]
    size = sum((h - l) ** 2 for l, h in zip(lo, hi)) ** 0.5
    top = max(vertices, key=lambda v: v[2])
    near = lambda v: sum((a - b) ** 2 for a, b in zip(v, top)) ** 0.5 < 0.35 * size
    kept = [f for f in faces if all(near(vertices[i]) for i in f)]
    used = sorted({i for f in kept for i in f})
    number = {i: n + 1 for n, i in enumerate(used)}
    lines = [f"v {-2 * y + 5:.6f} {2 * x:.6f} {2 * z - 3:.6f}" for x, y, z in (vertices[i] for i in used)]
    lines += ["f " + " ".join(str(number[i]) for i in f) for f in kept]
    return ("\n".join(lines) + "\n").encode()


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--url", default=os.environ.get("SALIENT_URL"))
    parser.add_argument("--key", default=os.environ.get("SALIENT_API_KEY"))
    parser.add_argument("--screenshots", default=os.environ.get(
        "SALIENT_SCREENSHOTS", str(ROOT / "target" / "browser-screenshots")))
    parser.add_argument("--headed", action="store_true", help="show the browser (debugging)")
    parser.add_argument("--timing-mesh", help="also time drop-to-results for this mesh (not a check)")
    args = parser.parse_args()
    if not args.url or not args.key:
        parser.error("the server URL and an API key are needed (--url, --key)")
    url = args.url.rstrip("/")
    shots = pathlib.Path(args.screenshots)
    shots.mkdir(parents=True, exist_ok=True)
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if not chromium:
        sys.exit("browser: no chromium on PATH (apt-get install chromium)")

    started = time.monotonic()
    passed = []
    phase = ["start"]
    doing = ["starting"]  # what the running check waits for, for the failure message

    console_errors = []

    def step(text):
        doing[0] = text

    def on_console(msg):
        if msg.type != "error":
            return
        where = (msg.location or {}).get("url", "")
        # Chromium logs every fetch that answers 4xx as "Failed to load resource: ... status of
        # N" (its own network log, not the page's error). Two such answers are expected and
        # handled by the page: the first library probe without a key (401, it opens the key
        # panel) and the upload of a file that is not a mesh (400 or 422, shown in #status).
        # Only those exact cases are let through; any other console error fails the run.
        if "Failed to load resource" in msg.text:
            if phase[0] == "key" and "status of 401" in msg.text and "/v1/models?limit=24" in where:
                return
            if phase[0] == "bad file" and ("status of 422" in msg.text or "status of 400" in msg.text) \
                    and "/v1/search" in where:
                return
        console_errors.append(f"[{phase[0]}] console.error: {msg.text} ({where})")

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium, headless=not args.headed,
                                    args=CHROMIUM_ARGS)
        context = browser.new_context(viewport={"width": 1280, "height": 900}, accept_downloads=True)
        page = context.new_page()
        page.set_default_timeout(UI_TIMEOUT_MS)
        page.on("console", on_console)
        page.on("pageerror", lambda err: console_errors.append(f"[{phase[0]}] page error: {err}"))

        def wait_thumbs(selector, what):
            step(f"the {what} thumbnails to load")
            page.wait_for_function(THUMBS_SETTLED, arg=selector, timeout=THUMBS_TIMEOUT_MS)
            broken = page.evaluate(BROKEN_THUMBS, selector)
            expect(not broken, f"{what}: thumbnails that did not load: {broken}")

        def results_changed(old_marker):
            # New results: a rank-1 card that is not the one marked before, and no request running.
            page.wait_for_function(
                """(m) => { const r = document.querySelector('.result[data-rank="1"]');
                  return r && r.dataset.marker !== m && !document.querySelector('#status.busy'); }""",
                arg=old_marker, timeout=SEARCH_TIMEOUT_MS)
            status = page.locator("#status")
            expect("error" not in (status.get_attribute("class") or ""),
                   f"the search failed: {status.text_content()}")

        def mark_results(marker):
            page.evaluate("""(m) => document.querySelectorAll('.result').forEach((r) => { r.dataset.marker = m; })""",
                          marker)

        # 1 --------------------------------------------------------------------------------
        def key_and_library():
            phase[0] = "key"
            page.goto(url + "/")
            expect(page.title() == "salient — 3D model search", f"title is {page.title()!r}")
            panel = page.locator("#key-panel")
            step("the key panel to appear after the first 401")
            panel.wait_for(state="visible")  # the first GET /v1/models answered 401
            page.fill("#api-key", args.key)
            page.click("#key-save")
            phase[0] = "library"
            step("7 .model elements in #library after saving the key")
            page.wait_for_function("() => document.querySelectorAll('#library .model').length >= 7")
            ids = sorted(page.eval_on_selector_all("#library .model", "els => els.map(e => e.dataset.modelId)"))
            expect(ids == LIBRARY, f"library shows {ids}, expected {LIBRARY}")
            expect(panel.is_hidden(), "the key panel stays open after a working key")
            wait_thumbs("#library .model", "library")
            stored = page.evaluate("() => sessionStorage.getItem('salient.apiKey')")
            expect(stored == args.key, "the key is not in sessionStorage under salient.apiKey")
            expect(args.key not in page.url, "the key is in the page's URL")
            return f"key panel on 401, {len(ids)} models with thumbnails"

        # 2 --------------------------------------------------------------------------------
        def upload_search():
            phase[0] = "upload"
            # Every state #status goes through, however brief (a fast server may answer before
            # a poll would see the busy state).
            page.evaluate("""() => { const s = document.querySelector('#status'); window.__statusLog = [];
              new MutationObserver(() => window.__statusLog.push([s.className, s.textContent]))
                .observe(s, { attributes: true, childList: true, characterData: true, subtree: true }); }""")
            t0 = time.monotonic()
            page.set_input_files("#query-file", str(FIXTURES / "capod" / "horse_m145.obj"))
            step('.result[data-rank="1"] after uploading horse_m145.obj')
            first = page.wait_for_selector('.result[data-rank="1"]', timeout=SEARCH_TIMEOUT_MS)
            elapsed = time.monotonic() - t0
            log = page.evaluate("() => window.__statusLog")
            expect(any("busy" in cls and "Extracting" in text for cls, text in log),
                   f"no busy 'Extracting…' status during the upload: {log}")
            top = first.get_attribute("data-model-id")
            expect(top == "horse_m145", f"rank 1 is {top}, expected horse_m145")
            n = page.locator(".result").count()
            expect(n == 7, f"{n} results, expected 7")
            shown = page.locator(".result .distance").first.text_content().strip()
            expect(re.search(r"\d\.\d{3}$", shown), f"the distance is not shown with 3 decimals: {shown!r}")
            wait_thumbs("#results .result", "results")
            print(f"browser: upload to results in {elapsed:.2f} s")
            return f"horse_m145 ranks first, {n} results in {elapsed:.2f} s"

        # 3 --------------------------------------------------------------------------------
        def view_3d():
            phase[0] = "3d view"
            step("the query's preview in the 3D view (#view[data-models=1])")
            page.wait_for_selector('#view[data-models="1"][data-drawn]', timeout=SEARCH_TIMEOUT_MS)
            page.screenshot(path=str(shots / "results.png"), full_page=True)
            target = page.locator('.result[data-rank="2"]')
            expect(target.count() == 1, "no rank-2 result to compare with")
            name = target.get_attribute("data-model-id")
            target.click(position={"x": 40, "y": 40})  # on the thumbnail, not on a button
            step(f"{name}'s preview beside the query (#view[data-models=2])")
            page.wait_for_selector(f'.result.selected[data-model-id="{name}"]')
            page.wait_for_selector(f'#view[data-models="2"][data-result="{name}"][data-drawn]')
            matches = int(page.get_attribute("#view", "data-matches") or 0)
            expect(matches > 0, "the hit has no explanation matches: no lines drawn")
            before = page.evaluate(READ_VIEW)
            total = before["width"] * before["height"]
            expect(before["drawn"] > total * 0.03,
                   f"the 3D view is nearly blank: {before['drawn']} of {total} pixels drawn")
            expect(before["colours"] >= 12, f"the 3D view has only {before['colours']} colours")
            expect(before["left"] > total * 0.005 and before["right"] > total * 0.005,
                   f"not two models side by side (left {before['left']}, right {before['right']} pixels)")
            expect(before["red"] > 0, "no red salient point markers")
            page.locator("#view").screenshot(path=str(shots / "view.png"))
            # Orbit: a drag must turn the scene.
            box = page.locator("#view").bounding_box()
            cx, cy = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
            frames = int(page.get_attribute("#view", "data-drawn"))
            page.mouse.move(cx, cy)
            page.mouse.down()
            page.mouse.move(cx + 120, cy + 30, steps=6)
            page.mouse.up()
            step("a frame drawn after the drag (#view[data-drawn] counts up)")
            page.wait_for_function("(n) => Number(document.querySelector('#view').dataset.drawn) > n", arg=frames)
            after = page.evaluate(READ_VIEW)
            expect(after["hash"] != before["hash"], "dragging did not rotate the 3D view")
            expect(after["drawn"] > total * 0.03, "the 3D view went blank after a drag")
            page.locator("#view").screenshot(path=str(shots / "view-rotated.png"))
            return (f"query and {name}: {before['drawn']} pixels, {before['colours']} colours, "
                    f"{matches} match lines; drag rotates")

        # 4 --------------------------------------------------------------------------------
        def bad_file():
            phase[0] = "bad file"
            mark_results("before-bad")
            page.set_input_files("#query-file", files=[{
                "name": "bad.obj", "mimeType": "text/plain",
                "buffer": (FIXTURES / "README.md").read_bytes()}])
            step("#status.error after uploading a file that is not a mesh")
            page.wait_for_selector("#status.error", timeout=SEARCH_TIMEOUT_MS)
            message = page.text_content("#status").strip()
            expect(len(message) > 10, f"the error message is empty: {message!r}")
            # The page still works: the previous results stay, usable.
            expect(page.locator('.result[data-rank="1"][data-marker="before-bad"]').count() == 1,
                   "the previous results were lost")
            return f"#status.error: {message}"

        # 5 --------------------------------------------------------------------------------
        def similar_and_method():
            phase[0] = "similar"
            mark_results("before-similar")
            step("results after 'similar' on chair_m35")
            page.click('#library .model[data-model-id="chair_m35"] .similar')
            results_changed("before-similar")
            ids = page.eval_on_selector_all(".result", "els => els.map(e => e.dataset.modelId)")
            expect(len(ids) == 6 and "chair_m35" not in ids,
                   f"similar to chair_m35 gave {ids} (expected the 6 others)")
            phase[0] = "method d2"
            mark_results("before-d2")
            step("results after choosing the d2 method")
            page.select_option("#method", "d2")
            results_changed("before-d2")
            summary = page.text_content("#results-summary")
            expect("D2" in summary, f"the results do not say D2: {summary!r}")
            n = page.locator(".result").count()
            expect(n == 6, f"d2 gave {n} results")
            wait_thumbs("#results .result", "d2 results")
            # And the 3D view of a "similar" query: the stored model's preview.
            top = page.locator('.result[data-rank="1"]')
            top_id = top.get_attribute("data-model-id")
            top.click(position={"x": 40, "y": 40})
            page.wait_for_selector(f'#view[data-models="2"][data-result="{top_id}"][data-drawn]',
                                   timeout=SEARCH_TIMEOUT_MS)
            page.screenshot(path=str(shots / "similar-d2.png"), full_page=True)
            return f"similar to chair_m35: {len(ids)} results; d2: {n} results"

        # 6 --------------------------------------------------------------------------------
        def part_search():
            phase[0] = "part search"
            # A part is searched among the stored patches, made in the background after each
            # upload: the server's gauge says when none is pending (the run serves /metrics).
            step("salient_patches_pending 0 on /metrics")
            deadline = time.monotonic() + SEARCH_TIMEOUT_MS / 1000
            while "salient_patches_pending 0" not in urllib.request.urlopen(url + "/metrics").read().decode():
                expect(time.monotonic() < deadline, "the stored models' patches were never made")
                time.sleep(0.2)
            step("#method disabled after choosing a part search")
            page.select_option("#mode", "partial")
            expect(page.is_disabled("#method"), "the method can still be chosen for a part search")
            mark_results("before-part")
            step("results of the horse's part (#results-summary names horse_part.obj)")
            page.set_input_files("#query-file", files=[{
                "name": "horse_part.obj", "mimeType": "text/plain", "buffer": horse_part()}])
            results_changed("before-part")
            page.wait_for_function(
                "() => document.querySelector('#results-summary').textContent.includes('horse_part.obj')",
                timeout=SEARCH_TIMEOUT_MS)
            summary = page.text_content("#results-summary")
            expect("as a part" in summary, f"the results do not say they are a part search's: {summary!r}")
            top = page.locator('.result[data-rank="1"]')
            source = top.get_attribute("data-model-id")
            expect(source == "horse_m145", f"the part's source is not first: {source}")
            shown = top.locator(".distance").text_content().strip()
            expect(shown.startswith("residual"), f"the source's card does not show its residual: {shown!r}")
            top.click(position={"x": 40, "y": 40})
            step("the part laid on its source (#view[data-placed][data-result=horse_m145][data-drawn])")
            page.wait_for_selector('#view[data-placed="1"][data-result="horse_m145"][data-drawn]',
                                   timeout=SEARCH_TIMEOUT_MS)
            seen = page.evaluate(READ_VIEW)
            total = seen["width"] * seen["height"]
            expect(seen["drawn"] > total * 0.03, f"the 3D view is nearly blank: {seen['drawn']} pixels")
            expect(seen["orange"] > total * 0.002, f"the placed part hardly shows: {seen['orange']} pixels")
            detail = page.text_content("#detail-distances")
            expect("registered: residual" in detail, f"the detail does not give the residual: {detail!r}")
            page.locator("#view").screenshot(path=str(shots / "part-placed.png"))
            page.screenshot(path=str(shots / "part-search.png"), full_page=True)
            return f"horse_part.obj: {source} first ({shown}), the part laid on it: {seen['orange']} pixels"

        # 7 --------------------------------------------------------------------------------
        def download():
            phase[0] = "download"
            step("a download from horse_m145's download button")
            with page.expect_download() as info:
                page.click('#library .model[data-model-id="horse_m145"] .download')
            dl = info.value
            expect(dl.suggested_filename == "horse_m145.obj",
                   f"the download is named {dl.suggested_filename!r}")
            saved = shots / "download.obj"
            dl.save_as(str(saved))
            expect(saved.read_bytes() == (FIXTURES / "capod" / "horse_m145.obj").read_bytes(),
                   "the downloaded file differs from the upload")
            saved.unlink()
            return "horse_m145.obj, byte for byte"

        # 8 --------------------------------------------------------------------------------
        def no_console_errors():
            phase[0] = "end"
            page.wait_for_timeout(200)
            page.screenshot(path=str(shots / "page.png"), full_page=True)
            expect(not console_errors, "errors in the console:\n  " + "\n  ".join(console_errors))
            return "none over the whole run"

        checks = [("key and library", key_and_library), ("upload search", upload_search),
                  ("3d view", view_3d), ("bad file", bad_file), ("similar and method", similar_and_method),
                  ("part search", part_search), ("download", download), ("console", no_console_errors)]
        failed = None
        for name, fn in checks:
            try:
                detail = fn()
                passed.append(name)
                print(f"browser: ok   {name}: {detail}", flush=True)
            except (CheckFailed, PlaywrightError) as err:
                failed = name
                reason = str(err).splitlines()[0] if isinstance(err, PlaywrightError) else str(err)
                if isinstance(err, PlaywrightError):
                    reason = f"{reason} (while waiting for {doing[0]})"
                print(f"browser: FAIL {name}: {reason}", file=sys.stderr, flush=True)
                try:
                    page.screenshot(path=str(shots / "failure.png"), full_page=True)
                    print(f"browser: the page at the failure: {shots / 'failure.png'}", file=sys.stderr)
                    print(f"browser: #status says: {page.text_content('#status')!r}", file=sys.stderr)
                except PlaywrightError:
                    pass
                if console_errors:
                    print("browser: console errors so far:\n  " + "\n  ".join(console_errors), file=sys.stderr)
                break
        if args.timing_mesh and not failed:
            # A measurement for the notes, not a check: upload to results with thumbnails shown.
            mark_results("before-timing")
            t0 = time.monotonic()
            page.set_input_files("#query-file", args.timing_mesh)
            results_changed("before-timing")
            wait_thumbs("#results .result", "timing")
            print(f"browser: drop to results with thumbnails for {args.timing_mesh}: "
                  f"{time.monotonic() - t0:.2f} s")
        browser.close()

    seconds = time.monotonic() - started
    if failed:
        print(f"browser: {len(passed)} passed, 1 failed")
        sys.exit(1)
    print(f"browser: {len(passed)} checks passed in {seconds:.1f} s (screenshots in {shots})")
    print(f"browser: {len(passed)} passed, 0 failed")


if __name__ == "__main__":
    main()

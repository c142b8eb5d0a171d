#!/usr/bin/env python3
"""Use a Prism report page (`report.html`) in a real headless browser as a reader would, and check it.

Opens the page from disk in Debian's Chromium (Selenium 4 driving the system chromedriver; nothing
is downloaded), waits for the slice viewer's first set to load, then:

- moves the z slider with the keyboard: the slice label and the method panels' pixels change;
- switches to another channel: the panels' pixels change;
- hovers over a panel: every panel reads a value at the same voxel (the linked cursor);
- turns on the residual view: the method panels become `method − reference` and change;
- takes screenshots (the report's head with Table II, the viewer after the slider moved, the
  residual view) into --screenshots;
- fails if the browser logged any error (a script exception, a file it could not load).

Prints one JSON object with what it measured; exits 1 when a check fails, 2 when no browser runs.
Used by tests/cli_html.rs.
"""

import argparse
import hashlib
import json
import shutil
import sys
from pathlib import Path


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("page", type=Path)
    ap.add_argument("--screenshots", type=Path, required=True)
    args = ap.parse_args()
    try:
        from selenium import webdriver
        from selenium.webdriver.chrome.options import Options
        from selenium.webdriver.chrome.service import Service
        from selenium.webdriver.common.action_chains import ActionChains
        from selenium.webdriver.common.by import By
        from selenium.webdriver.common.keys import Keys
        from selenium.webdriver.support.ui import WebDriverWait
    except ImportError as e:
        print(f"no browser: {e} (pip install selenium)", file=sys.stderr)
        return 2
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    driver_bin = shutil.which("chromedriver")
    if not chromium or not driver_bin:
        print("no browser: chromium and chromedriver must be on PATH (apt-get install chromium chromium-driver)",
              file=sys.stderr)
        return 2
    opts = Options()
    opts.binary_location = chromium
    for a in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--disable-gpu",
              "--window-size=1400,1000", "--force-device-scale-factor=1"):
        opts.add_argument(a)
    opts.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    args.screenshots.mkdir(parents=True, exist_ok=True)
    d = webdriver.Chrome(options=opts, service=Service(executable_path=driver_bin))
    checks: dict = {}
    failed: list = []

    def check(name: str, ok: bool, detail) -> None:
        checks[name] = {"ok": bool(ok), "detail": detail}
        if not ok:
            failed.append(name)

    try:
        d.set_page_load_timeout(60)
        d.get(args.page.resolve().as_uri())
        WebDriverWait(d, 60).until(lambda d: d.execute_script("return document.body.dataset.viewer") == "ready"
                                   or d.find_element(By.ID, "pv-status").text.startswith("cannot"))
        check("viewer loads", d.execute_script("return document.body.dataset.viewer") == "ready",
              d.find_element(By.ID, "pv-status").text)
        if failed:
            raise RuntimeError("the viewer did not load")
        tables = d.find_elements(By.CSS_SELECTOR, "#report table")
        check("tables render", len(tables) > 0, f"{len(tables)} tables")
        d.save_screenshot(str(args.screenshots / "1-report-head.png"))

        def panels():
            return d.execute_script(
                "return [...document.querySelectorAll('#pv-panels figure')].map(f => ["
                "f.querySelector('figcaption div').textContent, f.querySelector('canvas').toDataURL()])")

        def digest(ps):
            return {label: hashlib.sha1(url.encode()).hexdigest()[:12] for label, url in ps}

        def renders():
            return int(d.execute_script("return Number(document.body.dataset.renders || 0)"))

        before = digest(panels())
        # A page of runs made without --scene has no reference panel (and no residual view).
        check("panels", len(before) >= 1, sorted(before))
        z = d.find_element(By.ID, "pv-z")
        label0 = d.find_element(By.ID, "pv-z-label").text
        d.execute_script("arguments[0].scrollIntoView({block: 'start'})", d.find_element(By.ID, "slice-viewer"))
        z.send_keys(Keys.ARROW_RIGHT, Keys.ARROW_RIGHT, Keys.ARROW_RIGHT)
        label1 = d.find_element(By.ID, "pv-z-label").text
        after = digest(panels())
        changed = [k for k in before if after.get(k) != before[k]]
        check("slider moves z", label1 != label0, [label0, label1])
        check("slices change with z", len(changed) == len(before), changed)
        d.find_element(By.ID, "slice-viewer").screenshot(str(args.screenshots / "2-viewer-slider-moved.png"))

        buttons = d.find_elements(By.CSS_SELECTOR, "#pv-channels button")
        if len(buttons) > 1:
            n = renders()
            buttons[1].click()
            WebDriverWait(d, 10).until(lambda _: renders() > n)
            switched = digest(panels())
            check("channel switch changes every panel",
                  all(switched.get(k) != after[k] for k in after), buttons[1].text)
        else:
            switched = after
        canvas = d.find_elements(By.CSS_SELECTOR, "#pv-panels canvas")[0]
        ActionChains(d).move_to_element(canvas).perform()
        values = d.execute_script(
            "return [...document.querySelectorAll('#pv-panels .value')].map(v => v.textContent)")
        voxels = {v.split(":")[0] for v in values}
        check("linked cursor", all("mm⁻¹" in v for v in values) and len(voxels) == 1, values)

        residual = d.find_element(By.ID, "pv-residual")
        if residual.is_enabled():
            n = renders()
            residual.click()
            WebDriverWait(d, 10).until(lambda _: renders() > n)
            res = panels()
            labels = [label for label, _ in res]
            check("residual view", any("− reference" in lab for lab in labels)
                  and all(digest(res)[lab] != switched.get(lab.replace(" − reference", ""))
                          for lab in labels if "− reference" in lab), labels)
            d.find_element(By.ID, "slice-viewer").screenshot(str(args.screenshots / "3-viewer-residual.png"))
        errors = [e for e in d.get_log("browser") if e.get("level") == "SEVERE"]
        check("no console error", not errors, errors)
    except Exception as e:  # a failed wait or a missing element is a failed check
        check("page usable", False, f"{type(e).__name__}: {e}")
        try:
            errors = [e for e in d.get_log("browser") if e.get("level") == "SEVERE"]
            checks["console"] = errors
        except Exception:
            pass
    finally:
        d.quit()
    print(json.dumps({"page": str(args.page), "checks": checks, "failed": failed}, indent=1, ensure_ascii=False))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())

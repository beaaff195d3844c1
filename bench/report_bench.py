#!/usr/bin/env python3
"""How fast `voxfmt report` writes a library's report and how fast its page is in a browser.

    /usr/bin/python3 bench/report_bench.py --library out/library --json R.json --markdown R.md

Debian's python3 (Selenium from python3-selenium drives Debian's chromium headless; WebGL on the CPU). Two
libraries, one run:
  given      a baked library (default: out/library, the main job's CGAL sample meshes): `voxfmt report` with its
             pictures and 3D data (wall time, best of --repeat), the folder's size, and the page opened from
             file:// (time until its script has built the summary, plots and table, `readyMs`; a code filter)
  synthetic  a manifest of --meshes records (default 10,000) made here -- statuses, warnings and failures in the
             given library's proportions, sizes and times drawn around its own -- whose built assets are links
             to one small real asset, reported with --no-pictures (the page's cost, not 10,000 asset reads'
             pictures): the same figures, so the page's cost can be read against the number of meshes
Targets (issue 43): the CGAL report in <= 10 s on 2 cores and <= 20 MB, interactive in <= 2 s; 10,000 meshes
interactive in <= 3 s and a filter in <= 100 ms; no console error.
"""
import argparse
import json
import os
import platform
import random
import shutil
import subprocess
import sys
import tempfile
import time

from selenium import webdriver
from selenium.webdriver.chrome.service import Service

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)

FILTER_MS = """
const select = document.getElementById(arguments[0]);
const times = [];
for (const value of arguments[1]) {
  const t0 = performance.now();
  select.value = value;
  select.dispatchEvent(new Event('change'));
  document.getElementById('table-rows').offsetHeight;  // the layout is part of the cost
  times.push(performance.now() - t0);
}
return times;
"""

TYPE_MS = """
const input = document.getElementById('filter-name');
const t0 = performance.now();
for (const text of ['b', 'bu', 'bun', 'bunn', 'bunny', '']) {
  input.value = text;
  input.dispatchEvent(new Event('input'));
  document.getElementById('table-rows').offsetHeight;
}
return (performance.now() - t0) / 6;
"""


NOTES = """Targets: the CGAL library's report written in <= 10 s on 2 cores and <= 20 MB, interactive in <= 2 s;
10,000 meshes interactive in <= 3 s, a filter in <= 100 ms; no console error. *interactive* is the time from
navigation until the page's script has built the summary, the plots and the table (`readyMs`). The synthetic
library's write time is what reading 10,000 assets costs: every read of the toolchain runs in a child process (a
hostile file cannot crash the command), {ms_per_asset:.0f} ms per asset here; its pictures are left out
(--no-pictures)."""


def browser():
    options = webdriver.ChromeOptions()
    options.binary_location = "/usr/bin/chromium"
    for arg in ("--headless=new", "--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                "--window-size=1400,1000", "--disable-dev-shm-usage"):
        options.add_argument(arg)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    return webdriver.Chrome(service=Service("/usr/bin/chromedriver"), options=options)


def folder_bytes(path):
    return sum(os.path.getsize(os.path.join(d, f)) for d, _, files in os.walk(path) for f in files)


def write_report(voxfmt, library, out, extra, repeat):
    best = None
    for _ in range(repeat):
        t0 = time.perf_counter()
        p = subprocess.run([voxfmt, "report", library, "-o", out, "--json", *extra], capture_output=True, text=True)
        wall = time.perf_counter() - t0
        if p.returncode != 0:
            sys.exit("voxfmt report failed: %s" % p.stderr)
        best = wall if best is None else min(best, wall)
    return best, json.loads(p.stdout)


def measure_page(index_html):
    driver = browser()
    try:
        t0 = time.perf_counter()
        driver.get("file://" + os.path.abspath(index_html))
        for _ in range(600):
            if driver.execute_script("return document.body.dataset.ready") == "true":
                break
            time.sleep(0.01)
        load_wall = time.perf_counter() - t0
        ready = float(driver.execute_script("return document.body.dataset.readyMs"))
        codes = driver.execute_script(
            "return [...document.querySelectorAll('#filter-code option')].map(o => o.value).filter(v => v)")
        filter_ms = driver.execute_script(FILTER_MS, "filter-code", (codes + [""]) * 3) if codes else []
        type_ms = driver.execute_script(TYPE_MS)
        errors = [e["message"] for e in driver.get_log("browser") if e["level"] == "SEVERE"]
        return {"interactive_ms": round(ready, 1), "load_wall_ms": round(1000 * load_wall, 1),
                "filter_code_ms_max": round(max(filter_ms), 1) if filter_ms else None,
                "filter_name_ms_mean": round(type_ms, 1), "console_errors": errors}
    finally:
        driver.quit()


def synthetic_library(given, folder, meshes, seed=7):
    """A manifest of `meshes` records drawn from the given library's, built ones linked to one small asset."""
    records = []
    with open(os.path.join(given, "manifest.jsonl")) as f:
        for line in f:
            try:
                records.append(json.loads(line))
            except ValueError:
                pass
    built = [r for r in records if r.get("status") in ("ok", "up_to_date")]
    smallest = min(built, key=lambda r: r.get("file_size_bytes") or 1 << 60)
    source = smallest["output"] if os.path.exists(smallest["output"]) else os.path.join(given, os.path.basename(smallest["output"]))
    rng = random.Random(seed)
    os.makedirs(folder)
    with open(os.path.join(folder, "manifest.jsonl"), "w") as f:
        for i in range(meshes):
            r = dict(rng.choice(records))
            r.pop("command", None)
            name = "mesh%05d_%s" % (i, os.path.basename(r.get("input", "x.off")))
            r["input"] = os.path.join("/synthetic", name)
            r["output"] = os.path.join(folder, name + ".vox.h5")
            for key in ("total_s", "wall_s", "file_size_bytes", "input_triangles"):
                if isinstance(r.get(key), (int, float)):
                    r[key] = type(r[key])(r[key] * rng.uniform(0.5, 2.0))
            if r.get("status") in ("ok", "up_to_date"):
                os.symlink(os.path.abspath(source), r["output"])
            f.write(json.dumps(r) + "\n")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--library", default=os.path.join(ROOT, "out", "library"))
    ap.add_argument("--voxfmt", default=os.path.join(ROOT, "build", "bin", "voxfmt"))
    ap.add_argument("--meshes", type=int, default=10000, help="records of the synthetic manifest")
    ap.add_argument("--repeat", type=int, default=3, help="report writes per library (the best is kept)")
    ap.add_argument("--json")
    ap.add_argument("--markdown")
    args = ap.parse_args()
    if not os.path.isfile(os.path.join(args.library, "manifest.jsonl")):
        sys.exit("%s has no manifest.jsonl: run scripts/run-main.sh (or voxfmt batch) first" % args.library)

    tmp = tempfile.mkdtemp(prefix="voxfmt-report-bench-")
    try:
        results = []
        for label, library, extra, repeat in (("given", args.library, [], args.repeat),
                                              ("synthetic", os.path.join(tmp, "synthetic"), ["--no-pictures"], 1)):
            if label == "synthetic":
                synthetic_library(args.library, library, args.meshes)
            out = os.path.join(tmp, label + "-report")
            print("%s: writing the report of %s ..." % (label, library), file=sys.stderr)
            wall, summary = write_report(args.voxfmt, library, out, extra, repeat)
            print("%s: opening it in Chromium ..." % label, file=sys.stderr)
            page = measure_page(os.path.join(out, "index.html"))
            results.append({"library": label, "path": library, "meshes": summary["meshes"],
                            "pictures": label == "given", "write_s": round(wall, 2),
                            "report_mb": round(folder_bytes(out) / 1e6, 2), **page})
    finally:
        shutil.rmtree(tmp, ignore_errors=True)

    machine = {"cpus": os.cpu_count(), "platform": platform.platform(),
               "chromium": subprocess.run(["/usr/bin/chromium", "--version"], capture_output=True, text=True).stdout.strip()}
    doc = {"benchmark": "report", "machine": machine, "results": results,
           "targets": {"given_write_s": 10, "given_mb": 20, "given_interactive_ms": 2000,
                       "synthetic_interactive_ms": 3000, "filter_ms": 100}}
    lines = ["| library | meshes | pictures | write (s) | size (MB) | interactive (ms) | code filter, max (ms) | "
             "name filter, mean (ms) | console errors |", "|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        lines.append("| %s | %d | %s | %.2f | %.2f | %.0f | %s | %.1f | %d |" % (
            r["library"], r["meshes"], "yes" if r["pictures"] else "no", r["write_s"], r["report_mb"],
            r["interactive_ms"], r["filter_code_ms_max"], r["filter_name_ms_mean"], len(r["console_errors"])))
    table = "\n".join(lines)
    print(table)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(doc, f, indent=2)
    if args.markdown:
        with open(args.markdown, "w") as f:
            f.write("# voxfmt report: write time, size and page speed\n\n`%s` on %d CPUs, %s.\n\n%s\n\n%s\n" % (
                " ".join(["/usr/bin/python3", "bench/report_bench.py"] + sys.argv[1:]), machine["cpus"],
                machine["chromium"], table,
                NOTES.format(ms_per_asset=1000 * results[1]["write_s"] / results[1]["meshes"])))


if __name__ == "__main__":
    main()

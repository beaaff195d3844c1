"""The report in a real browser: headless Chromium (Debian's chromium and chromium-driver, driven by Selenium)
opens the report of a small library with failures, warnings and a damaged asset from file://, checks the counts
against the manifest, filters to one warning code, opens a failed mesh's card and reads its error code, opens
the 3D view and checks its canvas draws, reads the comparison with another bake, and finds no console error.
WebGL runs on the CPU (SwiftShader)."""
import json
import os
import shutil
import tempfile
import time
import unittest

from selenium import webdriver
from selenium.webdriver.chrome.service import Service
from selenium.webdriver.common.by import By
from selenium.webdriver.support.ui import Select, WebDriverWait

import report_fixture as fx

CHROMIUM = os.environ.get("VOXFMT_CHROMIUM", "/usr/bin/chromium")
CHROMEDRIVER = os.environ.get("VOXFMT_CHROMEDRIVER", "/usr/bin/chromedriver")


def browser():
    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for arg in ("--headless=new", "--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                "--window-size=1400,1000", "--disable-dev-shm-usage"):
        options.add_argument(arg)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    return webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)


def js_bytes(b):
    """The page's bytes(): how a size reads in its table, card and summary."""
    if b >= 1 << 30:
        return "%.2f GiB" % (b / (1 << 30))
    if b >= 1 << 20:
        return "%.1f MiB" % (b / (1 << 20))
    if b >= 1024:
        return "%.1f KiB" % (b / 1024)
    return "%d B" % b


# Every text a canvas draws, with where: the plots' tick labels (a y tick's starts at x = 4).
RECORD_CANVAS_TEXT = """
window.canvasTexts = [];
const fillText = CanvasRenderingContext2D.prototype.fillText;
CanvasRenderingContext2D.prototype.fillText = function (text, x, y) {
  window.canvasTexts.push([this.canvas.id, String(text), x, y]);
  return fillText.apply(this, arguments);
};
"""


def card_field(driver, label):
    """The card's value of a table row by its label ("" when there is none)."""
    cells = driver.find_elements(By.XPATH, "//aside[@id='card']//tr[th[text()='%s']]/td" % label)
    return cells[0].text if cells else ""


def card_headings(driver):
    return [h.text for h in driver.find_elements(By.CSS_SELECTOR, "#card h3")]


def open_page(driver, index_html):
    driver.get("file://" + os.path.abspath(index_html))
    WebDriverWait(driver, 20).until(lambda d: d.execute_script("return document.body.dataset.ready") == "true")
    return float(driver.execute_script("return document.body.dataset.readyMs"))


# Non-background pixels of the 3D view's canvas (its clear colour is #f3f5f8).
DRAWN_PIXELS = """
const c = document.querySelector('#viewer canvas');
if (!c) return -1;
const t = document.createElement('canvas'); t.width = c.width; t.height = c.height;
const g = t.getContext('2d'); g.drawImage(c, 0, 0);
const d = g.getImageData(0, 0, t.width, t.height).data;
let n = 0;
for (let i = 0; i < d.length; i += 4)
  if (Math.abs(d[i] - 243) + Math.abs(d[i + 1] - 245) + Math.abs(d[i + 2] - 248) > 24) ++n;
return n;
"""


class BrowserReportTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        for path in (CHROMIUM, CHROMEDRIVER):
            if not os.access(path, os.X_OK):
                raise AssertionError("%s is missing: scripts/install-deps.sh installs chromium and chromium-driver" % path)
        cls.tmp = tempfile.mkdtemp(prefix="voxfmt-report-browser-")
        cls.library, cls.other = fx.make_library(cls.tmp)
        cls.report = os.path.join(cls.tmp, "report")
        fx.run("report", cls.library, "-o", cls.report, "--against", cls.other)
        cls.records = fx.manifest(cls.library)
        cls.driver = browser()
        cls.driver.execute_cdp_cmd("Page.addScriptToEvaluateOnNewDocument", {"source": RECORD_CANVAS_TEXT})
        cls.ready_ms = open_page(cls.driver, os.path.join(cls.report, "index.html"))

    @classmethod
    def tearDownClass(cls):
        cls.driver.quit()
        shutil.rmtree(cls.tmp, ignore_errors=True)

    def setUp(self):
        close = self.driver.find_elements(By.CSS_SELECTOR, "#card .close")
        if close and close[0].is_displayed():
            close[0].click()
        self.driver.find_element(By.ID, "filter-clear").click()

    def tile(self, label):
        return self.driver.find_element(By.CSS_SELECTOR, '.tile[data-count="%s"] b' % label).text

    def rows_shown(self):
        return self.driver.find_element(By.ID, "filter-count").text

    def test_1_counts_match_the_manifest(self):
        print("page interactive in %.0f ms" % self.ready_ms)
        statuses = [r["status"] for r in self.records]
        self.assertEqual(self.tile("meshes"), str(len(self.records)))
        self.assertEqual(self.tile("built"), str(statuses.count("ok")))
        self.assertEqual(self.tile("failed"), str(statuses.count("failed")))
        self.assertEqual(self.tile("unreadable assets"), "1")
        # The damaged asset's bytes are a broken file's: not in the total (the manifest's recorded size neither).
        readable = [r for r in self.records if r["status"] == "ok" and not r["input"].endswith("damaged.obj")]
        self.assertEqual(self.tile("asset bytes"), js_bytes(sum(r["file_size_bytes"] for r in readable)))
        self.assertEqual(self.rows_shown(), "%d of %d meshes" % (len(self.records), len(self.records)))
        self.assertEqual(len(self.driver.find_elements(By.CSS_SELECTOR, "#table-rows .trow")), len(self.records))

    def test_2_filter_to_one_warning_code(self):
        with_border = [r for r in self.records if "OPEN_BORDER" in [w["code"] for w in r.get("warnings") or []]]
        self.assertTrue(with_border)
        Select(self.driver.find_element(By.ID, "filter-code")).select_by_value("OPEN_BORDER")
        self.assertEqual(self.rows_shown(), "%d of %d meshes" % (len(with_border), len(self.records)))
        names = [e.text for e in self.driver.find_elements(By.CSS_SELECTOR, "#table-rows .trow > div:first-child")]
        self.assertEqual(sorted(names), sorted(os.path.basename(r["input"]) for r in with_border))
        # The bar of a code filters too.
        self.driver.find_element(By.ID, "filter-clear").click()
        self.driver.find_element(By.CSS_SELECTOR, '.bar-label[data-code="OPEN_BORDER"]').click()
        self.assertEqual(self.rows_shown(), "%d of %d meshes" % (len(with_border), len(self.records)))

    def test_2b_filter_by_size_and_time(self):
        # An unreadable asset's size is its file's now, not the one the manifest recorded at bake; a failed mesh
        # has none (the hostile records carry a size all the same).
        damaged = os.path.getsize(os.path.join(self.library, "damaged.obj.vox.h5"))
        size = lambda r: (damaged if r["input"].endswith("damaged.obj") else
                          r.get("file_size_bytes", -1) if r["status"] == "ok" else -1)
        sizes = sorted(size(r) for r in self.records if size(r) >= 0)
        threshold = sizes[len(sizes) // 2] / 1048576  # the median, in MiB
        self.driver.find_element(By.ID, "filter-size").send_keys("%.6f" % (threshold - 1e-6))
        expected = sum(1 for r in self.records if size(r) >= (threshold - 1e-6) * 1048576)
        self.assertEqual(self.rows_shown(), "%d of %d meshes" % (expected, len(self.records)))
        self.driver.find_element(By.ID, "filter-clear").click()
        self.driver.find_element(By.ID, "filter-time").send_keys("100000")
        self.assertEqual(self.rows_shown(), "0 of %d meshes" % len(self.records))

    def test_3_failed_mesh_card_shows_its_error_code(self):
        failed = next(r for r in self.records if r["status"] == "failed")
        name = os.path.basename(failed["input"])
        self.driver.find_element(By.ID, "filter-name").send_keys(name)
        self.driver.find_element(By.CSS_SELECTOR, "#table-rows .trow").click()
        self.assertEqual(self.driver.find_element(By.ID, "card-name").text, name)
        self.assertEqual(self.driver.find_element(By.ID, "card-error-code").text, failed["error"]["code"])
        # No asset was written: no asset section naming a file that never existed.
        self.assertNotIn("Asset", card_headings(self.driver))
        self.assertEqual(card_field(self.driver, "file size"), "")

    def test_4_damaged_asset_card_shows_its_code(self):
        self.driver.find_element(By.ID, "filter-name").send_keys("damaged")
        self.driver.find_element(By.CSS_SELECTOR, "#table-rows .trow").click()
        self.assertRegex(self.driver.find_element(By.ID, "card-error-code").text, r"^[A-Z0-9_]+$")
        self.assertIn("invalid", self.driver.find_element(By.ID, "card-validation").text)
        # The file's size now; the manifest's figures under their own heading, as the bake's.
        now = os.path.getsize(os.path.join(self.library, "damaged.obj.vox.h5"))
        self.assertEqual(card_field(self.driver, "file size now"), js_bytes(now))
        self.assertIn("Recorded at bake (not this file now)", card_headings(self.driver))
        self.driver.find_element(By.CSS_SELECTOR, "#card .close").click()
        cells = self.driver.find_elements(By.CSS_SELECTOR, "#table-rows .trow > div")
        self.assertEqual(cells[5].text, js_bytes(now))  # the table's size column too
        self.assertEqual(cells[4].text, "")  # and no grid: the recorded one is not this file's

    def test_4b_built_asset_card_names_its_format_and_estimates(self):
        self.driver.find_element(By.ID, "filter-name").send_keys("tet.obj")
        self.driver.find_element(By.CSS_SELECTOR, "#table-rows .trow").click()
        # The provenance table comes from the asset's detail script, loaded after the card opens.
        rows = WebDriverWait(self.driver, 20).until(
            lambda d: {r.find_element(By.TAG_NAME, "th").text: r.find_element(By.TAG_NAME, "td").text
                       for r in d.find_elements(By.CSS_SELECTOR, "#card-provenance tr")} or None)
        self.assertEqual((rows.get("format"), rows.get("estimates")), ("2.2", "settled"))

    def test_5_3d_view_draws(self):
        self.driver.find_element(By.ID, "filter-name").send_keys("tet.obj")
        self.driver.find_element(By.CSS_SELECTOR, "#table-rows .trow").click()
        self.driver.find_element(By.ID, "open-3d").click()
        WebDriverWait(self.driver, 30).until(
            lambda d: d.find_elements(By.CSS_SELECTOR, "#viewer canvas") or d.find_elements(By.ID, "viewer-error"))
        self.assertFalse(self.driver.find_elements(By.ID, "viewer-error"))
        drawn = self.driver.execute_script(DRAWN_PIXELS)
        self.assertGreater(drawn, 500)
        # The surface and the slicing plane draw too: more pixels once both are on.
        self.driver.find_element(By.ID, "show-surface").click()
        self.driver.find_element(By.ID, "show-slice").click()
        self.assertGreater(self.driver.execute_script(DRAWN_PIXELS), drawn)
        # The level slider shows fewer points at the root.
        slider = self.driver.find_element(By.ID, "level")
        self.driver.execute_script("arguments[0].value = 0; arguments[0].dispatchEvent(new Event('input'))", slider)
        self.assertIn("levels 0–0 (1 points)", self.driver.find_element(By.ID, "level-label").text)

    def test_6_comparison_with_another_bake(self):
        counts = {e.get_attribute("data-change"): int(e.find_element(By.TAG_NAME, "td").text)
                  for e in self.driver.find_elements(By.CSS_SELECTOR, "#compare-counts tr")}
        self.assertEqual(counts["appeared"], 2)  # the hostile records
        self.assertEqual(counts["disappeared"], 0)
        # 24 against 96 voxels: smaller files everywhere something was built in both.
        self.assertGreater(counts["shrank"], 0)
        self.assertEqual(counts["grew"], 0)
        # Built in both manifests, but its asset here is unreadable: a change of state all the same.
        self.assertEqual(counts["status"], 1)
        line = self.driver.find_element(By.CSS_SELECTOR, '[data-change-list="status"] > div')
        self.assertEqual(line.get_attribute("data-output"), "damaged.obj.vox.h5")
        self.assertRegex(line.text, r"^damaged\.obj ok → unreadable [A-Z0-9_]+$")

    def test_6b_hostile_strings_stay_text(self):
        self.driver.find_element(By.ID, "filter-name").send_keys("<img")
        self.driver.find_element(By.CSS_SELECTOR, "#table-rows .trow").click()
        self.assertEqual(self.driver.find_element(By.ID, "card-name").text, "<img src=x onerror=alert(1)>.obj")
        self.assertIn("<script>alert(1)</script>", self.driver.find_element(By.ID, "card-error").text)
        self.assertFalse(self.driver.find_elements(By.CSS_SELECTOR, "#card img[src^='https'], script[src^='https']"))
        self.assertFalse(self.driver.find_elements(By.CSS_SELECTOR, "#card-pictures img"))
        # "__proto__" in a record gives it no inherited script or pictures.
        self.driver.find_element(By.CSS_SELECTOR, "#card .close").click()
        self.driver.find_element(By.ID, "filter-clear").click()
        self.driver.find_element(By.ID, "filter-name").send_keys("proto.obj")
        self.driver.find_element(By.CSS_SELECTOR, "#table-rows .trow").click()
        self.assertEqual(self.driver.find_element(By.ID, "card-name").text, "proto.obj")
        self.assertFalse(self.driver.find_elements(By.CSS_SELECTOR, "#card-pictures img, #open-3d"))
        self.assertFalse(self.driver.find_elements(By.CSS_SELECTOR, "script[src^='https'], script[src^='file']"))

    def test_6c_an_open_mesh_baked_solid_is_not_called_a_shell(self):
        self.driver.find_element(By.ID, "filter-name").send_keys("sheet")
        self.driver.find_element(By.CSS_SELECTOR, "#table-rows .trow").click()
        self.assertEqual(card_field(self.driver, "closed"), "no (open border)")  # OPEN_BORDER only: winding number

    def test_6d_same_names_say_where_they_lie(self):
        self.driver.find_element(By.ID, "filter-name").send_keys("tet.obj")
        cells = self.driver.find_elements(By.CSS_SELECTOR, "#table-rows .trow > div:first-child")
        self.assertEqual(sorted(c.get_attribute("title") for c in cells), ["parts/tet.obj.vox.h5", "tet.obj.vox.h5"])
        self.assertEqual(sorted(c.find_element(By.CLASS_NAME, "where").text for c in cells),
                         ["parts/tet.obj.vox.h5", "tet.obj.vox.h5"])

    def test_6e_a_tile_of_no_meshes_shows_its_filter(self):
        self.assertEqual(self.tile("up to date"), "0")
        self.driver.find_element(By.CSS_SELECTOR, '.tile[data-count="up to date"]').click()
        self.assertEqual(self.rows_shown(), "0 of %d meshes" % len(self.records))
        status = Select(self.driver.find_element(By.ID, "filter-status"))
        self.assertEqual(status.first_selected_option.text, "up to date")

    def test_6f_plot_ticks_name_their_powers_of_ten(self):
        texts = self.driver.execute_script("return window.canvasTexts")
        ticks = lambda canvas: [t for c, t, x, y in texts if c == canvas and x == 4]
        self.assertTrue(ticks("plot-time") and ticks("plot-size"))
        for t in ticks("plot-time"):
            self.assertRegex(t, r"^(1|10|100)(,000)* (µs|ms|s)$")
        for t in ticks("plot-size"):
            self.assertRegex(t, r"^(1|10|100) (B|kB|MB|GB|TB)$")

    def test_6g_a_narrow_window_scrolls_head_and_rows_together(self):
        try:
            self.driver.set_window_size(640, 1000)
            WebDriverWait(self.driver, 5).until(lambda d: d.execute_script("return window.innerWidth") < 700)
            state = self.driver.execute_script("""
              const t = document.getElementById('table'), body = document.getElementById('table-body');
              t.scrollLeft = 10000; body.scrollLeft = 10000;  // as far right as either goes
              const lefts = (cells) => [...cells].map((c) => Math.round(c.getBoundingClientRect().left));
              const de = document.documentElement;
              return { page: de.scrollWidth - de.clientWidth, table: t.scrollWidth - t.clientWidth,
                       head: lefts(document.querySelectorAll('#table-head > div')),
                       row: lefts(document.querySelector('#table-rows .trow').children) };""")
            self.assertLessEqual(state["page"], 0)  # no page-wide sideways scroll bar
            self.assertGreater(state["table"], 0)  # the table scrolls instead
            self.assertEqual(state["head"], state["row"])
        finally:
            self.driver.set_window_size(1400, 1000)

    def test_7_no_console_errors(self):
        errors = [e for e in self.driver.get_log("browser") if e["level"] == "SEVERE"]
        self.assertEqual(errors, [])


class BrowserEdgeCasesTest(unittest.TestCase):
    """A flat sheet baked as a shell, two failing meshes of one name in two subfolders against an older bake
    that built one of them, a file name wider than the card, and the same library without pictures."""

    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.mkdtemp(prefix="voxfmt-report-edges-")
        cls.library, cls.older = fx.make_edge_library(cls.tmp)
        cls.report, cls.plain = os.path.join(cls.tmp, "report"), os.path.join(cls.tmp, "plain")
        fx.run("report", cls.library, "-o", cls.report, "--against", cls.older)
        fx.run("report", cls.library, "-o", cls.plain, "--no-pictures")
        cls.driver = browser()

    @classmethod
    def tearDownClass(cls):
        cls.driver.quit()
        shutil.rmtree(cls.tmp, ignore_errors=True)

    def open_card(self, report, name):
        open_page(self.driver, os.path.join(report, "index.html"))
        self.driver.find_element(By.ID, "filter-name").send_keys(name)
        self.driver.find_element(By.CSS_SELECTOR, "#table-rows .trow").click()

    def test_comparison_keeps_same_names_apart(self):
        open_page(self.driver, os.path.join(self.report, "index.html"))
        counts = {e.get_attribute("data-change"): int(e.find_element(By.TAG_NAME, "td").text)
                  for e in self.driver.find_elements(By.CSS_SELECTOR, "#compare-counts tr")}
        self.assertEqual((counts["appeared"], counts["disappeared"], counts["status"]), (0, 0, 2))
        lines = {e.get_attribute("data-output"): e.text
                 for e in self.driver.find_elements(By.CSS_SELECTOR, '[data-change-list="status"] > div')}
        self.assertEqual(sorted(lines), ["a/x.obj.vox.h5", fx.LONG_NAME + ".vox.h5"])
        self.assertRegex(lines["a/x.obj.vox.h5"], r"^x\.obj \(a/x\.obj\.vox\.h5\) ok → failed [A-Z_]+$")
        # The older bake's asset is gone: it was not built there, whatever its manifest says.
        self.assertRegex(lines[fx.LONG_NAME + ".vox.h5"], r" unreadable FILE_NOT_FOUND → ok$")
        self.assertEqual([e for e in self.driver.get_log("browser") if e["level"] == "SEVERE"], [])

    def test_a_sheet_baked_as_a_shell_says_so(self):
        self.open_card(self.report, "flat.obj")
        self.assertEqual(card_field(self.driver, "closed"), "no (open border), baked as a shell")

    def test_a_long_name_does_not_widen_the_card(self):
        self.open_card(self.report, "long_")
        card = self.driver.find_element(By.ID, "card")
        self.assertEqual(self.driver.find_element(By.ID, "card-name").text, fx.LONG_NAME)
        overflow = self.driver.execute_script("return arguments[0].scrollWidth - arguments[0].clientWidth", card)
        self.assertLessEqual(overflow, 0)
        self.assertTrue(self.driver.find_elements(By.ID, "open-3d"))

    def test_no_3d_view_is_offered_without_its_data(self):
        self.open_card(self.plain, "long_")
        self.assertIn("valid", self.driver.find_element(By.ID, "card-validation").text)
        self.assertFalse(self.driver.find_elements(By.ID, "open-3d"))


class BrowserAssetCardTest(unittest.TestCase):
    def test_inspect_html_opens_on_its_card(self):
        tmp = tempfile.mkdtemp(prefix="voxfmt-card-browser-")
        try:
            mesh = os.path.join(tmp, "tet.obj")
            with open(mesh, "w") as f:
                f.write(fx.TET)
            asset = os.path.join(tmp, "tet.vox.h5")
            fx.run("build", mesh, "-o", asset, "--resolution", "24", "--points", "300")
            fx.run("inspect", asset, "--html", os.path.join(tmp, "card"))
            driver = browser()
            try:
                open_page(driver, os.path.join(tmp, "card", "index.html"))
                self.assertEqual(driver.find_element(By.ID, "card-name").text, "tet.vox.h5")
                self.assertIn("valid", driver.find_element(By.ID, "card-validation").text)
                # The library's parts have nothing to show for one asset: no chart frames, no empty headings.
                for part in ("plots", "summary", "library", "plot-time", "plot-size"):
                    self.assertFalse(driver.find_element(By.ID, part).is_displayed(), part)
                headings = [h.text for h in driver.find_elements(By.CSS_SELECTOR, "#card h3")]
                self.assertIn("Asset", headings)
                self.assertNotIn("Input", headings)
                self.assertIn("Bake settings", headings)  # from the asset's provenance, as `inspect` prints them
                self.assertRegex(driver.find_element(By.ID, "card").text, r"grid\s+\d+ × \d+ × \d+ voxels")
                for heading in driver.find_elements(By.CSS_SELECTOR, "#card h3"):
                    following = heading.find_element(By.XPATH, "following-sibling::*[1]")
                    self.assertNotEqual(following.tag_name, "h3", heading.text + " has nothing under it")
                self.assertEqual([e for e in driver.get_log("browser") if e["level"] == "SEVERE"], [])
            finally:
                driver.quit()
        finally:
            shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    unittest.main()

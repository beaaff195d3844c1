#!/usr/bin/env python3
"""The report's screenshots in docs/: a library's page, and one asset's card with its 3D view.

    /usr/bin/python3 scripts/report_screenshots.py out/library/report/index.html bunny00.off docs/

Debian's python3 with python3-selenium, chromium and chromium-driver (headless; WebGL on the CPU)."""
import os
import sys
import time

from selenium import webdriver
from selenium.webdriver.chrome.service import Service
from selenium.webdriver.common.by import By
from selenium.webdriver.support.ui import WebDriverWait


def main():
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    index, mesh, out = sys.argv[1:]
    options = webdriver.ChromeOptions()
    options.binary_location = "/usr/bin/chromium"
    for arg in ("--headless=new", "--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                "--window-size=1400,1000", "--hide-scrollbars"):
        options.add_argument(arg)
    driver = webdriver.Chrome(service=Service("/usr/bin/chromedriver"), options=options)
    try:
        driver.get("file://" + os.path.abspath(index))
        WebDriverWait(driver, 20).until(lambda d: d.execute_script("return document.body.dataset.ready") == "true")
        driver.save_screenshot(os.path.join(out, "report-library.png"))
        driver.find_element(By.ID, "filter-name").send_keys(mesh)
        driver.find_element(By.CSS_SELECTOR, "#table-rows .trow").click()
        driver.find_element(By.ID, "open-3d").click()
        WebDriverWait(driver, 30).until(lambda d: d.find_elements(By.CSS_SELECTOR, "#viewer canvas"))
        driver.find_element(By.ID, "show-surface").click()
        driver.find_element(By.ID, "show-slice").click()
        driver.execute_script("document.getElementById('viewer').scrollIntoView({block: 'start'})")
        driver.execute_script("document.getElementById('card').scrollTop -= 260")
        time.sleep(0.5)
        driver.save_screenshot(os.path.join(out, "report-3d-view.png"))
    finally:
        driver.quit()


if __name__ == "__main__":
    main()

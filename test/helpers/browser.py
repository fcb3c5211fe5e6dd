"""Headless Chromium through selenium (Debian's chromium + chromium-driver), for the page tests."""

from __future__ import annotations

import shutil
from pathlib import Path

CHROMIUM = ("chromium", "chromium-browser", "google-chrome")
DRIVERS = ("chromedriver", "chromium-driver")


def missing() -> str | None:
    """Why no headless browser can run here (None: it can)."""
    try:
        import selenium  # noqa: F401
    except ImportError:
        return "selenium is not installed (requirements.txt; scripts/setup_env.sh)"
    if not any(shutil.which(b) for b in CHROMIUM):
        return ("chromium is not installed (apt-get install chromium chromium-driver; "
                "scripts/setup_test_tools.sh does it as root)")
    if not any(shutil.which(d) for d in DRIVERS):
        return "chromedriver is not installed (apt-get install chromium-driver)"
    return None


def chromium(width: int = 1280, height: int = 900):
    """A headless Chromium WebDriver (the caller quits it)."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    opts.binary_location = next(shutil.which(b) for b in CHROMIUM if shutil.which(b))
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                f"--window-size={width},{height}", "--force-device-scale-factor=1", "--no-first-run",
                "--disable-extensions", "--disable-background-networking"):
        opts.add_argument(arg)
    driver_path = next(shutil.which(d) for d in DRIVERS if shutil.which(d))
    driver = webdriver.Chrome(service=Service(driver_path), options=opts)
    driver.set_page_load_timeout(20)
    return driver


def save_screenshot(driver, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    driver.save_screenshot(str(path))
    return path

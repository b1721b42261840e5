"""`station serve` for the tests: the command's server in a thread on a free loopback port
(`ServedStation`), and Debian's chromium driven through its chromedriver by Selenium
(`chromium`), never a browser or driver downloaded (Selenium Manager is not asked)."""

import os
import shutil
import threading
import time
from argparse import Namespace
from pathlib import Path

import pytest

CHROMIUM, CHROMEDRIVER = "/usr/bin/chromium", "/usr/bin/chromedriver"


class ServedStation:
    """`station serve --profile ... --port 0` in this process (a context manager): `url`, the
    `BenchSession` (`session`), the sessions folder. Stopped on exit, its session aborted."""

    def __init__(self, profiles: list, folder: Path, db: str | None = None, host="127.0.0.1",
                 token=None):
        from station.commands.serve import build_server

        self.folder = Path(folder)
        args = Namespace(profile=[Path(p) for p in profiles], host=host, port=0,
                         sessions=self.folder, token=token, db=db, no_db=db is None,
                         command="serve")
        self.server, self.session = build_server(args)
        self.url = f"http://{host}:{self.server.port}"
        self._thread = threading.Thread(target=self.server.serve, name="station-serve")

    def __enter__(self) -> "ServedStation":
        self._thread.start()
        deadline = time.monotonic() + 60
        while not self.server.server.started:
            if not self._thread.is_alive() or time.monotonic() > deadline:
                self.close()
                raise RuntimeError("station serve did not start")
            time.sleep(0.02)
        return self

    def __exit__(self, *_) -> None:
        self.close()

    def close(self) -> None:
        self.server.stop()
        self._thread.join(30)
        self.session.close()


def chromium(width: int = 1280, height: int = 1100):
    """A headless chromium under Selenium (quit it when done); skipped when chromium or its
    driver is not installed (`.ci/run` installs them, and there STATION_REQUIRE_BROWSER=1 makes
    their absence a failure)."""
    missing = [p for p in (CHROMIUM, CHROMEDRIVER) if not shutil.which(p)]
    if missing:
        words = (f"{' and '.join(missing)} missing: apt-get install -y chromium "
                 "chromium-driver")
        if os.environ.get("STATION_REQUIRE_BROWSER"):
            pytest.fail(words)
        pytest.skip(words)
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for flag in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                 f"--window-size={width},{height}", "--hide-scrollbars"):
        options.add_argument(flag)
    return webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)

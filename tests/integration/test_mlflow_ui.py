"""A real MLflow server on loopback: a small training logs to it, its REST API and UI show the run."""

import json
import os
import shutil
import subprocess
import sys
import urllib.request
from pathlib import Path

import pytest
from itest_servers import mlflow_server

pytestmark = pytest.mark.slow

RUN_NAME = "itest-ui-run"
PROJECT = Path(__file__).resolve().parents[2]


def _train(data, root, tracking_uri, run_name, extra=()):
    env = {**os.environ, "WORKBENCH_HOME": str(root), "MLFLOW_TRACKING_URI": tracking_uri}
    (root / "pipelines").mkdir(exist_ok=True)
    shutil.copy(PROJECT / "pipelines" / "learn.yaml", root / "pipelines" / "learn.yaml")
    cmd = [sys.executable, "-m", "workbench.cli", "train", "--data", str(data), "--tracking-uri", tracking_uri,
           "--run-name", run_name, "--out", str(root / "model"), "--quiet", "--register",
           "--set", "trainer.max_epochs=1", "--set", "data.train_windows_per_epoch=1024",
           "--set", "model.hidden_size=16", "--set", "model.num_layers=1", *extra]
    out = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=root, timeout=600)
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-3000:]
    return out


def _get(url):
    with urllib.request.urlopen(url, timeout=30) as r:
        return json.loads(r.read())


def _post(url, body):
    req = urllib.request.Request(url, data=json.dumps(body).encode(), headers={"Content-Type": "application/json"})
    with urllib.request.urlopen(req, timeout=30) as r:
        return json.loads(r.read())


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    root = tmp_path_factory.mktemp("mlflow-server")
    with mlflow_server(f"sqlite:///{root / 'server.db'}", root / "artifacts") as url:
        yield url


def test_training_against_a_server_is_read_back_over_rest_and_shown_in_the_ui(server, small_processed,
                                                                              tmp_path):
    _train(small_processed, tmp_path, server, RUN_NAME)
    exp = _get(f"{server}/api/2.0/mlflow/experiments/get-by-name?experiment_name=fed-lstm")["experiment"]
    runs = _post(f"{server}/api/2.0/mlflow/runs/search",
                 {"experiment_ids": [exp["experiment_id"]], "max_results": 50})["runs"]
    mine = [r for r in runs if r["info"]["run_name"] == RUN_NAME]
    assert len(mine) == 1
    run = mine[0]
    assert run["info"]["status"] == "FINISHED"
    tags = {t["key"]: t["value"] for t in run["data"].get("tags", [])}
    assert tags.get("campaign") == "itest-tunnel"
    assert "variant" in tags and "git_commit" in tags and "dvc_stage" in tags
    metrics = {m["key"] for m in run["data"].get("metrics", [])}
    assert any("val" in m for m in metrics), metrics
    # the registered model is visible through the server's registry API too
    reg = _get(f"{server}/api/2.0/mlflow/registered-models/get?name=fed-lstm")["registered_model"]
    assert reg["name"] == "fed-lstm"

    _assert_ui_lists_run(server, exp["experiment_id"], RUN_NAME, tmp_path)


def _assert_ui_lists_run(server, experiment_id, run_name, tmp_path):
    """Load the MLflow UI in real headless Chromium (Debian's, via chromedriver) and find the run."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service
    from selenium.webdriver.support.ui import WebDriverWait

    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    driver_bin = shutil.which("chromedriver")
    if chromium is None or driver_bin is None:
        pytest.fail("chromium and chromedriver are required (apt-get install chromium chromium-driver); "
                    ".ci/run installs them")
    opts = webdriver.ChromeOptions()
    opts.binary_location = chromium
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                "--disable-background-networking", "--disable-component-update", "--disable-sync",
                "--disable-dev-shm-usage", f"--user-data-dir={tmp_path / 'chrome'}", "--window-size=1400,1000"):
        opts.add_argument(arg)
    driver = webdriver.Chrome(service=Service(driver_bin), options=opts)
    try:
        driver.set_page_load_timeout(120)
        driver.get(f"{server}/#/experiments/{experiment_id}/runs")
        try:
            WebDriverWait(driver, 120, poll_frequency=1).until(lambda d: run_name in d.page_source)
        except Exception:
            driver.save_screenshot(str(tmp_path / "ui.png"))
            raise AssertionError(f"run {run_name!r} not listed in the MLflow UI; page text: "
                                 f"{driver.find_element('tag name', 'body').text[:1500]!r}") from None
        assert "fed-lstm" in driver.page_source
    finally:
        driver.quit()

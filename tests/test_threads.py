"""torch_threads settings: validation, and ``auto`` backing off when the cores are busy."""

import multiprocessing as mp
import os
import time
from pathlib import Path

import pytest

from workbench.errors import ParamsError
from workbench.threads import check_setting, idle_cores, resolve


def test_settings_accepted_and_refused():
    assert check_setting("auto") == "auto"
    assert check_setting(None) is None
    assert check_setting(3) == 3 and check_setting("2") == 2
    for bad in (0, -1, "many", 1.5, True):
        with pytest.raises(ValueError, match="torch_threads"):
            check_setting(bad)


def test_learn_and_gait_configs_refuse_a_bad_thread_count():
    from workbench.gait.config import config_from_dict as gait_config
    from workbench.learn.config import LearnSettings

    with pytest.raises(ParamsError, match=r"train\.trainer\.torch_threads: torch_threads must be"):
        LearnSettings().with_overrides({"trainer.torch_threads": 0})
    assert LearnSettings().with_overrides({"trainer.torch_threads": 2}).trainer.torch_threads == 2
    assert LearnSettings().trainer.torch_threads == "auto"
    import yaml

    params = Path(__file__).resolve().parents[1] / "pipelines" / "gait.yaml"
    doc = yaml.safe_load(params.read_text())["optimize"]
    assert gait_config(doc, params).torch_threads == "auto"
    with pytest.raises(ParamsError, match=rf"^{params}, optimize\.torch_threads: torch_threads must be"):
        gait_config({**doc, "torch_threads": "lots"}, params)


def _spin(seconds):
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        pass


def test_auto_uses_one_thread_when_every_core_is_busy():
    cores = len(os.sched_getaffinity(0))
    assert 1 <= idle_cores() <= cores
    procs = [mp.get_context("spawn").Process(target=_spin, args=(6.0,)) for _ in range(cores)]
    for p in procs:
        p.start()
    try:
        time.sleep(1.5)  # spawn start-up
        assert resolve("auto") == 1
    finally:
        for p in procs:
            p.terminate()
            p.join()
    assert resolve(4) == 4 and resolve(None) is None

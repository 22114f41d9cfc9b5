import sys
from pathlib import Path

import pytest

# tests in this folder import their models with memory (models.py) by module name
sys.path.insert(0, str(Path(__file__).parent))


@pytest.fixture(scope="session")
def robot():
    from workbench.hydro.robot import RobotSettings

    return RobotSettings()

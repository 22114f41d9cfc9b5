import sys
from pathlib import Path

# tests in this folder import their fixture builders (towing_fixture) by module name
sys.path.insert(0, str(Path(__file__).parent))

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ROOT / "configs"
VERIFICATION = CONFIGS / "verification"
sys.path.insert(0, str(Path(__file__).resolve().parent))  # tests/analytical.py

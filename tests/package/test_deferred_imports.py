"""What the model's import costs a start: ``import fault_screen.api`` (what ``fault-screen run``
imports before it builds the model) brings in no module that only a fallback, a figure or another
command needs. Counted in a fresh interpreter (sys.modules), never timed."""
from __future__ import annotations

import json
import subprocess
import sys

#: imported where they are used: SuperLU (``bordered_lu``'s fallback when the LDL^T does not
#: hold), figures, seismic catalogs in miniSEED/QuakeML
DEFERRED = ("scipy.sparse.linalg", "matplotlib", "obspy")


def test_the_model_imports_no_fallback_and_no_figures():
    code = ("import sys, json, fault_screen.api\n"
            "print(json.dumps(sorted(sys.modules)))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    modules = json.loads(out.stdout.strip().splitlines()[-1])
    assert "fault_screen.bordered_lu" in modules and "scipy.sparse" in modules
    loaded = sorted(m for m in modules if any(m == d or m.startswith(d + ".") for d in DEFERRED))
    assert loaded == [], loaded

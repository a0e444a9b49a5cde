"""An effect that is off costs nothing at start-up: numba loads (or compiles) a kernel at its
first call, so the kernels of the rock's pore pressure and of rate-dependent friction are never
loaded by a scene without them. Checked in a fresh interpreter (each kernel's signatures list
is empty until its first call)."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SCENE = ROOT / "configs" / "hard-cases" / "far-from-failure.toml"

CODE = """
import json, sys
from fault_screen import Scene, Simulation
from fault_screen.kernels import contact, fault_flow, rock
scene = Scene.from_toml(sys.argv[1])
sim = Simulation(scene)
sim.advance(3 * scene.time.dt)
effects = scene.effects
kernels = {f"{m.__name__.rsplit('.', 1)[1]}.{n}": len(getattr(m, n).signatures)
           for m, names in ((rock, ("elastic_stiffness_all", "biot_coupling_all", "darcy_conductance_all",
                                    "pore_storage_all")),
                            (contact, ("coulomb_law", "rate_state_law")))
           for n in names}
print(json.dumps(dict(poroelastic=effects.poroelastic, rate_friction=effects.rate_friction, kernels=kernels)))
"""


def test_kernels_of_effects_that_are_off_are_never_loaded():
    out = subprocess.run([sys.executable, "-c", CODE, str(SCENE)], capture_output=True, text=True,
                         cwd=ROOT, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["poroelastic"] is False and got["rate_friction"] is False
    assert got["kernels"] == {"rock.elastic_stiffness_all": 1, "rock.biot_coupling_all": 0,
                              "rock.darcy_conductance_all": 0, "rock.pore_storage_all": 0,
                              "contact.coulomb_law": 1, "contact.rate_state_law": 0}

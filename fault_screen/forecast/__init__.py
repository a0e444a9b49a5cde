"""Forecasts: what the fault will do under an injection plan, from any state of a run.

:mod:`~fault_screen.forecast.plans` reads plans (``scene``, ``hold``, ``stop``,
``rate:30 L/min``, ``scale:1.2``, a log file); :class:`~fault_screen.forecast.lookahead.LookAhead`
runs each plan on a fork of the simulation (``Simulation.fork``) for a horizon and screens it
with the scene's ``[monitor]`` rules; :func:`~fault_screen.forecast.advice.advise` bisects for
the largest constant rate that stays below a level; :mod:`~fault_screen.plotting.forecast` draws
``<stem>-forecast.png``. The layer sits above screening and below the monitor and the CLI::

    from fault_screen import Scene, Simulation
    from fault_screen.screening.stepwise import StepScreening
    from fault_screen.forecast import LookAhead, parse_plan

    scene = Scene.from_toml("configs/rustrel-2015-impermeable.toml")
    sim = Simulation(scene)
    fp = sim.disc.fault_points
    screening = StepScreening.for_scene(scene, fp.s - sim.disc.injection.s, fp.weight)
    screening.screen_simulation(sim)
    while sim.advance(300.0, align=True, max_steps=1):
        screening.screen_simulation(sim)
    ahead = LookAhead(sim, screening)
    print(ahead.run(parse_plan("hold"), 600.0).row())
"""
from .advice import Advice, advise
from .lookahead import COLUMNS, Forecast, LookAhead, StepLadder
from .plans import Plan, PlanError, largest_rate_so_far, parse_duration, parse_plan

__all__ = ["Advice", "advise", "COLUMNS", "Forecast", "LookAhead", "Plan", "PlanError", "StepLadder",
           "largest_rate_so_far", "parse_duration", "parse_plan"]

"""The words of the run summary and the verdict, as an operator reads them."""
import re
from pathlib import Path

import pytest

from fault_screen.cli._running import _summary, format_volume, fluid_destinations, unit_reading
from fault_screen.cli._verdict import verdict_lines, watched_lines


@pytest.mark.parametrize("volume, text", [
    (0.93833, "938.3 L"),          # below 1 m3: litres
    (0.0005, "0.5 L"),
    (1.0, "1 m3"),                 # from 1 m3: cubic metres, never 1000 L
    (11581.0, "11,581 m3"),        # the Basel stimulation, not "1.1581e+07 L"
    (2.5e5, "250,000 m3"),
])
def test_volumes_in_litres_below_one_cubic_metre_and_cubic_metres_beyond(volume, text):
    assert format_volume(volume) == text


def test_si_reading_summary_and_green_verdict_say_what_to_do_and_what_is_watched(bundled_run,
                                                                                capsys):
    """The SI reading of the calibrated Rustrel scene stays green; its summary names the SI
    reading and points to the paper-units scene, uses no internal terms, and the GREEN verdict
    gives the action and one line per threshold watched (5 in the default [monitor]: slip rate
    1e-6 and 1e-3 m/s, utilisation 0.9, magnitudes 2 and 2.9)."""
    from fault_screen.screening import screen_result

    result = bundled_run("rustrel-2015-calibrated")
    _summary(result, Path("r.h5"), [], None)
    text = capsys.readouterr().out
    assert re.search(r"paper's units\s+k_f read as a permeability in m2 divided by water's "
                     r"viscosity \(SI\).*rustrel-2015-calibrated-paper-units\.toml", text)
    for internal in ("jump where", "elastic give", "creep at rest", "leaked through edges"):
        assert internal not in text
    # fault + rock + out of the block: the budget's percentages, in words (0.741 % in the fault)
    assert re.search(r"injected fluid\s+0\.74\d? % in the fault, 96\.\d %", text)

    lines = verdict_lines(screen_result(result, store=False))
    assert lines[0] == "verdict: GREEN"
    assert "keep injecting as planned" in lines[1]
    watched = watched_lines(result.scene.monitor)
    assert len(watched) == 5
    assert "yellow: fault sliding: peak_slip_rate > slip_rate_yellow (1e-06 m/s)" in watched
    assert "yellow: near failure: max_utilisation > utilisation_yellow (0.9)" in watched
    assert "red: dynamic slip: peak_slip_rate > slip_rate_red (0.001 m/s)" in watched
    assert all(f"    {w}" in lines for w in watched)


def test_unit_reading_follows_the_scene_not_its_file_name():
    """The line is decided by what the rock holds (a mobility or a permeability), for the
    Rustrel scenes only."""
    from conftest import CONFIGS
    from fault_screen import Scene

    paper = Scene.from_toml(CONFIGS / "rustrel-2015-calibrated-paper-units.toml")
    si = Scene.from_toml(CONFIGS / "rustrel-2015-calibrated.toml")
    assert unit_reading(paper).startswith("k_f read as a mobility")
    assert unit_reading(si).startswith("k_f read as a permeability")
    assert unit_reading(si.replace(title="another fault")) is None


def test_fluid_destinations_in_plain_words(bundled_run):
    """The three destinations add up to the injected volume to within the budget's error."""
    from fault_screen.budget import fluid_budget

    result = bundled_run("rustrel-2015-calibrated")
    b = fluid_budget(result)
    numbers = [float(x) for x in re.findall(r"([0-9.]+) %", fluid_destinations(result))]
    assert sum(numbers) == pytest.approx(100.0 - b.unaccounted_percent, abs=0.05)

"""bench/bench_status_clients.py runs in a tiny configuration and prints its figures (never
asserted: the machine may be busy; tests/test_bench_smoke.py does the same for the others)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_bench_status_clients_prints_every_figure() -> None:
    args = ["--seconds", "0.6", "--rounds", "1", "--calls", "20"]
    proc = subprocess.run(
        [sys.executable, "bench/bench_status_clients.py", *args],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    assert result["bench"] == "status_clients"
    figures = result["figures"]
    for kind in ("none", "reading", "stuck"):
        assert figures[f"{kind}_frames"] > 1
        assert figures[f"{kind}_p99_error_ms"] >= 0
        assert 0 < figures[f"{kind}_tick_p50_ms"] <= figures[f"{kind}_tick_p99_ms"]
        assert figures[f"{kind}_inside_p99_error_ms"] >= 0
    assert "reading_minus_none_tick_p99_ms" in figures
    assert figures["json_dumps_us_median"] > 0
    assert figures["line_us_median"] >= figures["json_dumps_us_median"]

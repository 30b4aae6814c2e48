"""bench/bench_replay.py runs in a tiny configuration and prints the figures it names."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_bench_replay_prints_its_figures() -> None:
    for clock in ([], ["--virtual"]):
        done = subprocess.run(
            [sys.executable, "bench/bench_replay.py", "--seconds", "0.2", *clock],
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=120,
            check=True,
        )
        figures = json.loads(done.stdout.strip().splitlines()[-1])["figures"]
        assert figures["replay_reports"] > 0
        assert figures["replay_cpu_us_per_report"] > 0
        assert "replay_cpu_us_per_report" in done.stdout

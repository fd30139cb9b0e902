"""The committed bad-input sweep in its quick form (tools/badinput_sweep.py --quick): every
command on inputs that are outputs, full disks, closed streams, hostile numbers, huge and cut
images, huge frame numbers and an interrupt; every case must hold."""

from __future__ import annotations

import os
import re
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def test_quick_sweep_holds_every_case():
    env = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
    p = subprocess.run([sys.executable, os.path.join(ROOT, "tools", "badinput_sweep.py"), "--quick", "--seed", "1"],
                       cwd=ROOT, capture_output=True, text=True, timeout=540, env=env)
    m = re.search(r"seed 1: (\d+) cases, (\d+) held", p.stdout)
    assert m, p.stdout + p.stderr
    cases, held = map(int, m.groups())
    assert cases >= 26 and held == cases and p.returncode == 0, p.stdout

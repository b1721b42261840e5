"""What `station solve` of a rotary session costs beyond its work (issue 35): no scipy on its path
(scipy's import alone costs more than numpy's and h5py's; the quality gate's tails are
station.solve.tails), and the structure check forked from the command when it runs one thread
(numpy and h5py inherited, not imported again by a new interpreter)."""

import json
import subprocess
import sys
from pathlib import Path

EXAMPLE = Path(__file__).resolve().parents[1] / "sessions" / "rotary-12gyro.h5"


def test_a_rotary_solve_imports_no_scipy_and_forks_its_check(tmp_path):
    code = ("import json, subprocess, sys\n"
            "from station.cli import main\n"
            "started = []\n"
            "popen = subprocess.Popen.__init__\n"
            "def counted(self, *a, **k):\n"
            "    started.append(a[0])\n"
            "    popen(self, *a, **k)\n"
            "subprocess.Popen.__init__ = counted\n"
            f"code = main(['solve', {str(EXAMPLE)!r}, '--out', {str(tmp_path / 'x.cal.json')!r},"
            " '--no-db'])\n"
            "print(json.dumps([code, sorted(m for m in sys.modules if m.startswith('scipy')),"
            " started]))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=tmp_path)
    code, scipy, started = json.loads(out.stdout.splitlines()[-1])
    assert code == 0 and (tmp_path / "x.cal.json").exists()
    assert scipy == []
    # the check's child was forked, no interpreter started (h5py's import runs `uname -p`)
    assert [cmd for cmd in started if cmd[0] == sys.executable] == []

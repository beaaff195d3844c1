"""Compiling MJCF models that name voxfmt assets in a child interpreter: a refused asset must be a MuJoCo error
that names the voxfmt code, and never take the interpreter down (tests/mujoco, tests/reads)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

CHILD = r"""
import json, sys
import mujoco, voxfmt.mujoco as vm
vm.load_plugin()
results = []
for path in json.loads(sys.argv[1]):
    xml = ('<mujoco><extension><plugin plugin="voxfmt.sdf.asset"><instance name="a">'
           f'<config key="file" value="{path}"/></instance></plugin></extension>'
           '<asset><mesh name="a"><plugin instance="a"/></mesh></asset>'
           '<worldbody><body><freejoint/><geom type="sdf" mesh="a"><plugin instance="a"/></geom></body></worldbody>'
           '</mujoco>')
    try:
        model = mujoco.MjModel.from_xml_string(xml)
        mujoco.MjData(model)
        results.append([path, None, ""])
    except Exception as e:
        results.append([path, type(e).__name__, str(e)])
print(json.dumps(results))
"""


def compile_in_child(paths: list[str]) -> list[list]:  # type: ignore[type-arg]
    """[path, exception type name or None, message] per path, each compiled into a model and given MjData."""
    env = dict(os.environ)
    child = subprocess.run([sys.executable, "-c", CHILD, json.dumps(paths)], capture_output=True, text=True,
                           env=env, timeout=240)
    assert child.returncode == 0, f"the interpreter died ({child.returncode}): {child.stderr[-2000:]}"
    return json.loads(child.stdout.strip().splitlines()[-1])

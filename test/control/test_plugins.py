"""Controllers by spec: registered names (entry points, the built-ins' and an installed
package's), ``package.module:factory``, and one line for every way a spec can fail."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from dlmpc_ros.control.factory import CONTROLLERS
from dlmpc_ros.control.paper_loops import PaperDLMPC
from dlmpc_ros.control.step import MODES, AngleLimits
from dlmpc_ros.control.plugins import ControllerSpecError, build, label, registered
from dlmpc_ros.evaluation.runs import RunSpec, run_fast
from dlmpc_ros.examples.hill_climber import HillClimber
from dlmpc_ros.paths import models_dir

HERE = 'test.control.plugin_examples'


def install(root: Path, name: str, entry_points: dict[str, str]) -> Path:
    """A distribution ``name`` that registers ``entry_points`` as controllers, as pip
    would install it (a .dist-info folder; ``root`` goes on the path)."""
    info = root / f'{name}-0.1.dist-info'
    info.mkdir(parents=True)
    (info / 'METADATA').write_text(f'Metadata-Version: 2.1\nName: {name}\nVersion: 0.1\n')
    (info / 'entry_points.txt').write_text(
        '[dlmpc_ros.controllers]\n' + ''.join(f'{k} = {v}\n' for k, v in entry_points.items()))
    return root


def test_the_built_in_controllers_are_registered_like_any_other():
    names = registered()
    assert set(CONTROLLERS) <= set(names)
    for name in CONTROLLERS:
        assert names[name] == f'dlmpc_ros.control.factory:{name}'
    assert build('fixed_best', models_dir()).name == 'fixed_best'


def test_the_paper_s_dl_mpc_is_a_registered_controller_without_the_added_parts():
    paper = build('dlmpc_paper', models_dir(), AngleLimits())
    assert isinstance(paper, PaperDLMPC) and paper.acquisition is None
    assert [mode.name for mode in paper.modes] == ['outer', 'inner', 'hold']
    # it reads the VAE's surrogate, so the harness runs the estimator for it as for dlmpc
    record = run_fast(RunSpec('sinusoidal', 1, 'dlmpc_paper', round_trips=60), models_dir())
    assert np.isfinite(record.surrogate).all() and set(record.mode) <= {MODES.index('inner')}


def test_an_installed_package_registers_a_name(tmp_path, monkeypatch):
    example = 'dlmpc_ros.examples.hill_climber:make'
    monkeypatch.syspath_prepend(str(install(tmp_path, 'mylab', {'mylab_hill': example})))
    assert registered()['mylab_hill'] == example
    limits = AngleLimits(max_step=0.1)
    controller = build('mylab_hill', models_dir(), limits)
    assert isinstance(controller, HillClimber) and controller.limits is limits
    # a second package claiming a name already taken is refused, in one line
    install(tmp_path / 'other', 'otherlab', {'esc': f'{HERE}:wants_angles'})
    monkeypatch.syspath_prepend(str(tmp_path / 'other'))
    with pytest.raises(ControllerSpecError, match="'esc' is registered twice"):
        build('esc', models_dir())


def test_a_factory_gets_only_the_settings_it_names():
    angles = np.array([0.1, 0.2, 0.3, 0.4])
    holder = build(f'{HERE}:wants_angles', models_dir(), angles=angles, initial_k=0.2)
    assert holder.settings == {'angles': angles}  # never the true K it did not ask for
    assert holder.models_dir == models_dir() and isinstance(holder.limits, AngleLimits)
    with pytest.raises(TypeError, match='offers only'):
        build('esc', models_dir(), true_k=0.1)


@pytest.mark.parametrize('spec, words', [
    ('teleport', ["unknown controller 'teleport'", 'registered are bo, dlmpc, ',
                  'package.module:factory']),
    ('test.control.no_such_module:make', ["cannot import 'test.control.no_such_module'",
                                          'ModuleNotFoundError']),
    (f'{HERE}:nothing', [f"'{HERE}' has no 'nothing'"]),
    (f'{HERE}:Path.cwd.__name__', ['is a str, not a factory']),
    (f'{HERE}:raises', ['its factory raised FileNotFoundError: no calibration in this lab']),
    (f'{HERE}:not_a_controller', ["returned 'str', not a controller", 'str name']),
    ('passive', ['passive needs its angles or the initial K']),
    ('', ['must be a name or package.module:factory']),
])
def test_every_bad_spec_is_one_line_saying_which_and_why(spec, words):
    with pytest.raises(ControllerSpecError) as caught:
        build(spec, models_dir())
    message = str(caught.value)
    assert '\n' not in message
    for word in words:
        assert word in message, message


def test_a_spec_is_a_file_name():
    assert label('esc') == 'esc'
    assert label('my_lab.es:make') == 'my_lab.es-make'


def test_the_documented_example_is_the_shipped_file():
    root = Path(__file__).resolve().parents[2]
    code = (root / 'dlmpc_ros' / 'examples' / 'hill_climber.py').read_text()
    assert f'```python\n{code}```' in (root / 'docs' / 'controllers.md').read_text()
    assert len(code.splitlines()) <= 45

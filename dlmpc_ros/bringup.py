"""bringup: start the dlmpc_ros node graph without ROS launch, watch it, stop it cleanly.

Starts each node as its own process with its parameter file from ``config/``: the laser
simulator, the drift injector and the controller chosen by ``--controller`` (``dlmpc``
adds the VAE estimator; any other name or ``package.module:factory`` runs in the
baseline_controller node, docs/controllers.md). Waits until the graph is connected
(state and K messages arrive), prints a live status line, optionally writes every round
trip (and every control decision) to CSV and plots it, and stops after ``--round-trips``
or Ctrl-C.
With ``--respawn`` a node that exits unexpectedly (crash, kill) is restarted, with a line
on standard error, at most ``--max-restarts`` times a minute; by default every node but
the laser simulator, whose restart would begin a new run at round trip 1.
Each node's log is ``<log dir>/<node>.log`` and the pid of its current process is in
``<log dir>/<node>.pid`` while the graph runs.
Exit code: 0 on a clean run, 1 if a node died (and was not restarted) or did not stop
cleanly, 2 for bad arguments, a controller that cannot be built or a graph that never
connected.
"""

from __future__ import annotations

import signal
import sys

# A Ctrl-C while the modules below load ends the bringup quietly (nothing runs yet);
# main() takes the signals over before it starts any node.
for _signal in (signal.SIGINT, signal.SIGTERM):
    signal.signal(_signal, lambda *_: sys.exit(0))

import argparse
import fcntl
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from dlmpc_ros import interfaces as itf
from dlmpc_ros.control.factory import CONTROLLERS
from dlmpc_ros.control.plugins import ControllerSpecError, build
from dlmpc_ros.control.step import MEASUREMENT_ROUND_TRIPS
from dlmpc_ros.core.bench import BENCH_FIELDS, BENCH_PRESETS, parse_bench
from dlmpc_ros.core.config import CavityConfig
from dlmpc_ros.core.drift import SCENARIOS, make_scenario, parse_settings
from dlmpc_ros.core.plants import NOMINAL, PHYSICS_FIELDS, parse_plant, plant_parameters
from dlmpc_ros.graph import NodeGraph, NodeProcess
from dlmpc_ros.paths import config_file

#: Nodes the bringup knows: name -> (module, parameter file).
NODES = {
    'laser_sim': ('dlmpc_ros.nodes.laser_sim_node', 'laser_sim.yaml'),
    'drift_injector': ('dlmpc_ros.nodes.drift_injector_node', 'drift_injector.yaml'),
    'vae_estimator': ('dlmpc_ros.nodes.vae_estimator_node', 'vae_estimator.yaml'),
    'mpc_controller': ('dlmpc_ros.nodes.mpc_controller_node', 'mpc_controller.yaml'),
    'baseline_controller': ('dlmpc_ros.nodes.baseline_controller_node',
                            'baseline_controller.yaml'),
    'recorder': ('dlmpc_ros.nodes.recorder_node', 'recorder.yaml'),
}
#: ``explore``: the DL-MPC exploring turns of its curve, to record a calibration bag.
CONTROLLER_CHOICES = (*CONTROLLERS, 'dlmpc_paper', 'explore', 'none')
#: Controller names that run the mpc_controller node (with the vae_estimator), and the
#: node parameters each sets: ``dlmpc_paper`` is the node's ``strategy:=paper``, as the
#: registered controller of that name is in dlmpc-evaluate.
DLMPC_STRATEGIES: dict[str, dict] = {'dlmpc': {}, 'dlmpc_paper': {'strategy': 'paper'},
                                     'explore': {'plan_explore': True}}
#: Nodes that subscribe /laser/state (the simulator holds round trip 1 until they do).
#: Topics each node publishes that the recorder waits for before the run starts.
PUBLISHES = {
    'laser_sim': (itf.TOPIC_SIM_TRUTH, itf.TOPIC_OBJECTIVE, itf.TOPIC_LASER_STATUS),
    'drift_injector': (itf.TOPIC_BIREFRINGENCE,),
    'vae_estimator': (itf.TOPIC_ESTIMATE,),
    'mpc_controller': (itf.TOPIC_ANGLES_CMD, itf.TOPIC_CONTROLLER_STATUS),
    'baseline_controller': (itf.TOPIC_ANGLES_CMD, itf.TOPIC_CONTROLLER_STATUS),
}
STATE_READERS = ('drift_injector', 'mpc_controller', 'baseline_controller', 'recorder')
DEFAULT_DOMAIN_ID = 87


def controller_nodes(controller: str) -> list[str]:
    """Nodes that make up ``--controller``."""
    if controller == 'none':
        return []
    if controller in DLMPC_STRATEGIES:
        return ['vae_estimator', 'mpc_controller']
    return ['baseline_controller']


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog='bringup', description=__doc__.split('\n\n')[0])
    p.add_argument('--controller', default='dlmpc', metavar='NAME|MODULE:FACTORY',
                   help=f'controller to run: one of {", ".join(CONTROLLER_CHOICES)}, another '
                        'registered name, or package.module:factory (docs/controllers.md) '
                        '(default: %(default)s; oracle reads the true K and is for '
                        'evaluation only; none: open loop)')
    p.add_argument('--nodes', default='laser_sim,drift_injector',
                   help='comma-separated simulator-side nodes to start (default: '
                        '%(default)s); leave out laser_sim to run against a hardware driver')
    p.add_argument('--period', type=int, default=10,
                   help='control period P in round trips (default: %(default)s)')
    p.add_argument('--measurement-round-trips', type=int, default=MEASUREMENT_ROUND_TRIPS,
                   metavar='N',
                   help="the estimator and controller read each period's E and M as the "
                        'mean of its last N round trips at its angles (default: '
                        "%(default)s; more divide a detector's noise)")
    p.add_argument('--lockstep', action='store_true',
                   help='the simulator waits for each command and K (reproducible runs)')
    p.add_argument('--initial-angles', metavar='A1,A2,A3,AP',
                   help='initial angles of the simulated laser [rad]')
    p.add_argument('--models-dir', type=Path,
                   help='model files for the controller (default: the installed models/)')
    p.add_argument('--controller-param', action='append', default=[], metavar='KEY=VALUE',
                   help='controller node parameter override, repeatable (e.g. track_guard=0.9)')
    p.add_argument('--scenario', default='sinusoidal', choices=SCENARIOS,
                   help='birefringence drift scenario (default: %(default)s)')
    p.add_argument('--scenario-param', action='append', default=[], metavar='KEY=VALUE',
                   help='drift scenario setting, repeatable (e.g. period=2000)')
    p.add_argument('--laser-param', action='append', default=[], metavar='KEY=VALUE',
                   help='laser_sim parameter override, repeatable (e.g. pump=1.8)')
    p.add_argument('--plant', action='append', default=[], metavar='KEY=VALUE',
                   help='a physical parameter of the simulated cavity, repeatable (one of '
                        f'{", ".join(PHYSICS_FIELDS)}); only laser_sim gets it')
    p.add_argument('--bench', action='append', default=[], metavar='PRESET|KEY=VALUE',
                   help='emulate the lab bench in laser_sim, repeatable: a preset ('
                        f'{", ".join(BENCH_PRESETS)}) or a setting ({", ".join(BENCH_FIELDS)}; '
                        'docs/nodes.md)')
    p.add_argument('--plant-family', type=int, metavar='SEED',
                   help='simulate plant SEED of the family of core/plants.py (drawn and '
                        'checked to mode-lock at every K once, then cached)')
    p.add_argument('--round-trips', type=int, default=0,
                   help='stop after this many laser round trips (0: run until Ctrl-C)')
    p.add_argument('--rate', type=float, default=0.0,
                   help='laser round trips per second (0: as fast as possible)')
    p.add_argument('--domain-id', type=int,
                   help=f'ROS_DOMAIN_ID of the graph (default: the exported ROS_DOMAIN_ID, '
                        f'else {DEFAULT_DOMAIN_ID}); a second bringup on a domain in use is '
                        'refused')
    p.add_argument('--discovery', choices=('localhost', 'subnet'), default='localhost',
                   help='ROS_AUTOMATIC_DISCOVERY_RANGE (default: %(default)s keeps the graph '
                        'off the network)')
    p.add_argument('--csv', type=Path, help='write every round trip (state and K) here')
    p.add_argument('--record', type=Path, metavar='DIR',
                   help='record every /laser, /estimator and /controller topic to a rosbag2 '
                        'bag (MCAP) in DIR (must not exist); the recorder stops last')
    p.add_argument('--plot', type=Path, help='plot O and K of the run to this PNG at the end')
    p.add_argument('--log-dir', type=Path, help='node logs (default: ~/.ros/log/dlmpc_ros/<time>)')
    p.add_argument('--connect-timeout', type=float, default=120.0,
                   help='seconds to wait for the graph to connect (default: %(default)s)')
    p.add_argument('--stop-timeout', type=float, default=10.0,
                   help='seconds a node gets to exit after SIGINT (default: %(default)s)')
    p.add_argument('--respawn', nargs='?', const='', metavar='NODE,...',
                   help='restart nodes that exit unexpectedly: the named ones, or without a '
                        'list every node but laser_sim')
    p.add_argument('--max-restarts', type=int, default=3,
                   help='most restarts of one node per minute before the run stops '
                        '(default: %(default)s)')
    args = p.parse_args(argv)
    args.nodes = [n.strip() for n in args.nodes.split(',') if n.strip()]
    args.nodes += [n for n in controller_nodes(args.controller) if n not in args.nodes]
    if args.record is not None:
        if args.record.exists():
            p.error(f'--record {args.record} exists; choose a new directory')
        args.nodes.append('recorder')
    unknown = [n for n in args.nodes if n not in NODES]
    if unknown:
        p.error(f'unknown node(s) {unknown}; known: {sorted(NODES)}')
    args.domain_from_env = args.domain_id is None and bool(os.environ.get('ROS_DOMAIN_ID'))
    if args.domain_id is None:
        try:
            args.domain_id = int(os.environ.get('ROS_DOMAIN_ID') or DEFAULT_DOMAIN_ID)
        except ValueError:
            p.error(f"ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']!r} is not a domain id")
    if not 0 <= args.domain_id <= 232:
        p.error('--domain-id must be in 0..232')
    if args.respawn is None:
        args.respawn = []
    elif args.respawn == '':
        args.respawn = [n for n in args.nodes if n != 'laser_sim']
    else:
        args.respawn = [n.strip() for n in args.respawn.split(',') if n.strip()]
        if not set(args.respawn) <= set(args.nodes):
            p.error(f'--respawn names node(s) not started: '
                    f'{sorted(set(args.respawn) - set(args.nodes))}; started: {args.nodes}')
    if args.max_restarts < 0:
        p.error('--max-restarts must be >= 0')
    try:
        args.scenario_settings = parse_settings(args.scenario_param)
        if 'path' in args.scenario_settings:  # nodes may run elsewhere than here
            args.scenario_settings['path'] = str(Path(args.scenario_settings['path']).resolve())
        make_scenario(args.scenario, **args.scenario_settings)  # fail here, not in a node
        args.laser_overrides = {**plant_overrides(args),
                                **parse_bench(args.bench).to_dict(),
                                **dict(_laser_override(item) for item in args.laser_param)}
        args.controller_overrides = dict(_laser_override(item)
                                         for item in args.controller_param)
        if args.initial_angles is not None:
            angles = [float(x) for x in args.initial_angles.split(',')]
            if len(angles) != 4 or not np.isfinite(angles).all():
                raise ValueError('--initial-angles needs 4 finite numbers')
            args.laser_overrides['initial_angles'] = angles
    except (ValueError, FileNotFoundError) as err:
        p.error(str(err))
    if args.rate < 0 or args.round_trips < 0 or args.period < 1:
        p.error('--rate and --round-trips must be >= 0, --period >= 1')
    if args.measurement_round_trips < 1:
        p.error('--measurement-round-trips must be >= 1')
    return args


def plant_overrides(args: argparse.Namespace) -> dict[str, float]:
    """laser_sim's physical parameters for ``--plant`` and ``--plant-family`` (empty: the
    nominal cavity)."""
    if args.plant and args.plant_family is not None:
        raise ValueError('give --plant or --plant-family, not both')
    if args.plant_family is not None:
        from dlmpc_ros.core.plants import PlantFamily
        from dlmpc_ros.learning.tables import load_baselines
        from dlmpc_ros.paths import models_dir
        from dlmpc_ros.training.envelope import draw_plant
        tables = load_baselines(models_dir(args.models_dir or '') / 'oracle.npz')
        plant, _ = draw_plant(PlantFamily(), args.plant_family, tables)
        return plant_parameters(plant)
    if args.plant:
        return {k: v for k, v in plant_parameters(parse_plant(args.plant)).items()
                if v != plant_parameters(NOMINAL)[k]}
    return {}


def _laser_override(item: str) -> tuple[str, object]:
    """``KEY=VALUE`` to a typed laser_sim parameter (floats stay floats: ``pump=2``)."""
    key, sep, text = item.partition('=')
    if not sep:
        raise ValueError(f'bad parameter {item!r}: use KEY=VALUE')
    default = CavityConfig().to_dict().get(key)
    if isinstance(default, float):
        return key, float(text)
    if text.lower() in ('true', 'false'):
        return key, text.lower() == 'true'
    for kind in (int, float):
        try:
            return key, kind(text)
        except ValueError:
            pass
    return key, text


def build_graph(args: argparse.Namespace, env: dict[str, str], log_dir: Path) -> NodeGraph:
    nodes = []
    scenario = make_scenario(args.scenario, **args.scenario_settings)
    controlled = args.controller != 'none'
    for name in args.nodes:
        module, params = NODES[name]
        overrides: dict[str, object] = {}
        if name == 'laser_sim':
            # Hold round trip 1 until the monitor and every state reader listen, and
            # start from the scenario's K of round trip 1.
            readers = 1 + sum(n in args.nodes for n in STATE_READERS)
            overrides = {'round_trips_per_second': float(args.rate),
                         'wait_for_subscribers': readers, **args.laser_overrides}
            if args.lockstep:
                overrides['lockstep_period'] = args.period if controlled else 0
                overrides['lockstep_birefringence'] = 'drift_injector' in args.nodes
            if 'drift_injector' in args.nodes:
                overrides.setdefault('initial_birefringence', float(scenario(1)))
        elif name == 'drift_injector':
            overrides = {'scenario': args.scenario, **args.scenario_settings}
        elif name == 'vae_estimator':
            if args.models_dir is not None:
                overrides['models_dir'] = str(args.models_dir.resolve())
        elif name in ('mpc_controller', 'baseline_controller'):
            overrides = {'period': args.period,
                         'measurement_round_trips': args.measurement_round_trips}
            if args.models_dir is not None:
                overrides['models_dir'] = str(args.models_dir.resolve())
            if name == 'mpc_controller':
                overrides.update(DLMPC_STRATEGIES[args.controller])
            overrides.update(args.controller_overrides)
            if name == 'baseline_controller':
                overrides['controller'] = args.controller
                if 'drift_injector' in args.nodes:
                    # passive: the setting a person tuned for the simulated laser's initial
                    # K, then left alone (a driver's laser: the node's parameter)
                    overrides.setdefault('initial_birefringence', float(scenario(1)))
        elif name == 'recorder':
            # append: a recorder restarted after a crash continues the bag (a new file)
            overrides = {'output': str(args.record.resolve()), 'append': True,
                         'wait_for_publishers': ','.join(
                             t for n in args.nodes for t in PUBLISHES.get(n, ()))}
        nodes.append(NodeProcess(name, module, config_file(params), overrides,
                                 respawn=name in args.respawn, stop_last=name == 'recorder'))
    return NodeGraph(nodes, env, log_dir, max_restarts=args.max_restarts)


#: Middleware settings a caller's environment may hold that would change the graph's
#: discovery or transports; the bringup passes on only its own.
MIDDLEWARE_PREFIXES = ('FASTDDS_', 'FASTRTPS_', 'RMW_FASTRTPS_', 'CYCLONEDDS_')
MIDDLEWARE_NAMES = ('ROS_STATIC_PEERS', 'ROS_LOCALHOST_ONLY', 'ROS_DISCOVERY_SERVER',
                    'ROS_SUPER_CLIENT')


def graph_environment(args: argparse.Namespace, base: dict[str, str]
                      ) -> tuple[dict[str, str], list[str]]:
    """The environment of the graph's processes and the caller's middleware settings left
    out. Discovery ``localhost`` keeps discovery and data on loopback (Fast DDS profile
    ``config/fastdds_loopback.xml``: UDP on 127.0.0.1 and shared memory); ``subnet``
    uses the middleware's defaults."""
    dropped = sorted(k for k in base if k.startswith(MIDDLEWARE_PREFIXES)
                     or k in MIDDLEWARE_NAMES)
    env = {k: v for k, v in base.items() if k not in dropped}
    env['ROS_DOMAIN_ID'] = str(args.domain_id)
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'SUBNET'
    if args.discovery == 'localhost':
        # SUBNET discovery over a loopback-only transport: every socket on 127.0.0.1 (the
        # LOCALHOST range of the rmw opens sockets on every interface beside its own)
        env['FASTRTPS_DEFAULT_PROFILES_FILE'] = str(config_file('fastdds_loopback.xml'))
    return env, dropped


def claim_domain(domain: int):
    """Hold a lock on ``domain`` for this process (an open file; closed at exit), or
    ValueError naming the bringup that holds it: two graphs on one domain merge."""
    directory = Path(tempfile.gettempdir()) / 'dlmpc_ros'
    directory.mkdir(exist_ok=True)
    handle = open(directory / f'domain-{domain}.lock', 'a+')
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        handle.seek(0)
        owner = handle.read().strip() or 'another process'
        handle.close()
        raise ValueError(f'a dlmpc_ros graph already runs on ROS domain {domain} ({owner}); '
                         'give another --domain-id (two graphs on one domain merge)') from None
    handle.seek(0)
    handle.truncate()
    handle.write(f'bringup pid {os.getpid()}')
    handle.flush()
    return handle


def check_controller(args: argparse.Namespace) -> str | None:
    """Why the baseline_controller node could not build ``--controller`` (one line), or
    None: the bringup builds it once itself, so that a bad spec stops it at start."""
    if 'baseline_controller' not in args.nodes:
        return None
    from dlmpc_ros.paths import models_dir
    given = args.controller_overrides  # what the node gets beside its parameter file
    initial_k = given.get('initial_birefringence')
    if initial_k is None and 'drift_injector' in args.nodes:
        initial_k = float(make_scenario(args.scenario, **args.scenario_settings)(1))
    angles = given.get('angles')
    try:
        build(args.controller, models_dir(args.models_dir or ''), initial_k=initial_k,
              angles=np.array(angles, float) if isinstance(angles, list) else None)
    except ControllerSpecError as err:
        return str(err)
    return None


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    problem = check_controller(args)
    if problem is not None:
        print(f'bringup: {problem}', file=sys.stderr)
        return 2
    try:
        lock = claim_domain(args.domain_id)  # noqa: F841 (held until the process ends)
    except ValueError as err:
        print(f'bringup: {err}', file=sys.stderr)
        return 2
    env, dropped = graph_environment(args, dict(os.environ))
    os.environ.clear()
    os.environ.update(env)  # the monitor node of this process joins the same graph
    log_dir = args.log_dir or Path.home() / '.ros' / 'log' / 'dlmpc_ros' / time.strftime(
        '%Y%m%d-%H%M%S')
    graph = build_graph(args, env, log_dir)
    plant = {k: v for k, v in args.laser_overrides.items() if k in PHYSICS_FIELDS}
    print(f'bringup: domain {args.domain_id}'
          f'{" (from ROS_DOMAIN_ID)" if args.domain_from_env else ""}, discovery '
          f'{args.discovery}, controller {args.controller}'
          f'{" (lockstep)" if args.lockstep else ""}, nodes {", ".join(args.nodes)}, logs in '
          f'{log_dir}{", respawn " + ",".join(args.respawn) if args.respawn else ""}'
          f'{", plant " + str(plant) if plant else ""}', flush=True)
    if dropped:
        print(f'bringup: not passing on the middleware settings {", ".join(dropped)} '
              '(the graph uses its own)', flush=True)
    from dlmpc_ros.ros.stop_signals import stop_on_signals
    # From here a Ctrl-C only sets a flag: raised inside rclpy's C extension, which takes a
    # second or more to load, it failed the import with a traceback. One that comes before
    # the graph starts ends the bringup quietly; later, it stops the graph in order.
    requested = stop_on_signals()
    from dlmpc_ros.ros.monitor import run_monitor  # rclpy only from here on
    if requested.is_set():
        return 0
    graph.start()
    try:
        code = run_monitor(args, graph, requested, lambda code: stop_graph(args, graph, code))
    finally:
        graph.stop(args.stop_timeout)  # a no-op once run_monitor has stopped it
    if args.plot is not None and args.csv is not None and args.csv.exists():
        plot(args, plant)
    return code


def stop_graph(args: argparse.Namespace, graph: NodeGraph, code: int) -> int:
    """Stop every node, say which were restarted or did not exit cleanly; returns the
    bringup's exit code (at least 1 if a node did not exit cleanly)."""
    exit_codes = graph.stop(args.stop_timeout)
    restarts = {n.name: n.restart_count for n in graph.nodes if n.restart_count}
    if restarts:
        print(f'bringup: nodes restarted during the run (times): {restarts}', flush=True)
    unclean = {name: c for name, c in exit_codes.items() if c != 0}
    if unclean:
        print(f'bringup: nodes that did not exit cleanly: {unclean}', file=sys.stderr)
        code = max(code, 1)
    return code


def plot(args: argparse.Namespace, plant: dict[str, float]) -> None:
    """The run's figure (with a controller: beside the uncontrolled laser and O*(K(t)),
    and a summary line; else O and K)."""
    from dlmpc_ros.recording.run_csv import decisions_path
    if args.controller == 'none' or not decisions_path(args.csv).exists():
        from dlmpc_ros.plotting import plot_run_csv
        plot_run_csv(args.csv, args.plot)
        print(f'bringup: plot written to {args.plot}')
        return
    from dataclasses import replace

    from dlmpc_ros.evaluation.demo import demo_report
    from dlmpc_ros.learning.tables import load_baselines
    from dlmpc_ros.paths import models_dir
    envelope = None if plant else load_baselines(
        models_dir(args.models_dir or '') / 'oracle.npz')
    try:
        line = demo_report(args.csv, args.plot, args.controller, replace(NOMINAL, **plant),
                           args.period, envelope)
    except ValueError as err:
        print(f'bringup: no plot: {err}', file=sys.stderr)
        return
    print(f'bringup: plot written to {args.plot}\nbringup: {line}', flush=True)


if __name__ == '__main__':
    sys.exit(main())

"""ament_python package setup; console scripts go to lib/dlmpc_ros via setup.cfg (colcon)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = 'dlmpc_ros'

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*', 'bench']),
    data_files=[
        ('share/ament_index/resource_index/packages', [f'resource/{PACKAGE}']),
        (f'share/{PACKAGE}', ['package.xml']),
        (f'share/{PACKAGE}/config', glob('config/*.yaml') + glob('config/*.xml')),
        (f'share/{PACKAGE}/models', glob('models/*.*')),
    ],
    python_requires='>=3.10',
    install_requires=[
        'setuptools',
        'numpy>=1.26',
        'scipy>=1.11',
        'numba>=0.60',
        'rocket-fft>=0.2.5',
        'matplotlib>=3.7',
        'pyyaml',
        'rosbags>=0.11,<0.12',
        'dask>=2024.1',
        'distributed>=2024.1',
        # the Bayesian-optimization baseline's Gaussian process (control/bo.py)
        'scikit-learn>=1.5,<2',
    ],
    extras_require={'ml': ['torch>=2.2,<3', 'tqdm>=4.60'],
                    # dlmpc_ros.gym only (docs/gym.md); the nodes never import it
                    'gym': ['gymnasium>=1.0,<2'],
                    # dlmpc-train drl only (training/drl.py); the drl controller runs numpy
                    'drl': ['gymnasium>=1.0,<2', 'stable-baselines3>=2.3,<3',
                            'torch>=2.2,<3']},
    zip_safe=True,
    maintainer='dlmpc_ros developers',
    maintainer_email='dlmpc-ros@example.org',
    description='Self-tuning mode-locked fiber laser simulation and DL-MPC control for ROS 2',
    license='MIT',
    entry_points={
        'console_scripts': [
            f'laser_sim = {PACKAGE}.nodes.laser_sim_node:main',
            f'drift_injector = {PACKAGE}.nodes.drift_injector_node:main',
            f'vae_estimator = {PACKAGE}.nodes.vae_estimator_node:main',
            f'mpc_controller = {PACKAGE}.nodes.mpc_controller_node:main',
            f'baseline_controller = {PACKAGE}.nodes.baseline_controller_node:main',
            f'bringup = {PACKAGE}.bringup:main',
            f'dlmpc-sim = {PACKAGE}.cli.sim:main',
            f'dlmpc-data = {PACKAGE}.cli.data:main',
            f'dlmpc-train = {PACKAGE}.cli.train:main',
            f'dlmpc-evaluate = {PACKAGE}.cli.evaluate:main',
            f'dlmpc-check-laser = {PACKAGE}.cli.check_laser:main',
            f'recorder = {PACKAGE}.nodes.recorder_node:main',
            f'dlmpc-bag = {PACKAGE}.cli.bag:main',
        ],
        # controllers by name (docs/controllers.md): any installed package may add its own
        f'{PACKAGE}.controllers': [
            f'{name} = {PACKAGE}.control.factory:{name}'
            for name in ('dlmpc', 'dlmpc_paper', 'esc', 'ga', 'passive', 'fixed_best',
                         'oracle', 'bo', 'drl')
        ],
    },
)

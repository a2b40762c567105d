"""vae_estimator: the VAE's K surrogate from what is measured, once per decision.

Subscribes ``/controller/measurement``, the measurement ``(E, M, alpha[4])`` each of the
controller's decisions is made on (E and M averaged over its settled round trips, with
their angles: :mod:`dlmpc_ros.control.step`), feeds it to the VAE encoder and
publishes ``/estimator/birefringence`` ``[r, surrogate, latency_ms, latent mean...]`` for
the same round trip r. The surrogate is a coordinate of the latent space that tracks K,
not K in K's units.
"""

from __future__ import annotations

import math
import sys
import time

import numpy as np
from rclpy.node import Node
from std_msgs.msg import Float64MultiArray

from dlmpc_ros import interfaces as itf
from dlmpc_ros.control.factory import load_estimator
from dlmpc_ros.health import WARN, CounterWindow, Findings, Health
from dlmpc_ros.learning.model_files import ModelFileError
from dlmpc_ros.paths import models_dir
from dlmpc_ros.ros import params
from dlmpc_ros.ros.diagnostics import DiagnosticsPublisher
from dlmpc_ros.ros.io import QOS, vector_message

DEFAULTS: dict[str, object] = {'models_dir': ''}
DESCRIPTIONS = {'models_dir': 'directory holding vae_encoder.npz (empty: the installed '
                              'models/)'}


class VAEEstimatorNode(Node):
    def __init__(self) -> None:
        super().__init__('vae_estimator')
        values = params.declare(self, DEFAULTS, DESCRIPTIONS, frozenset(DEFAULTS), {})
        try:
            self.estimator = load_estimator(models_dir(values['models_dir']))
        except (ModelFileError, FileNotFoundError) as err:
            raise params.StartupError(str(err)) from None
        self._warn = itf.RateLimitedLog(self.get_logger().warning)
        self.published = 0
        self._last_measurement: float | None = None
        self._latency_ms = math.nan
        self._drops = CounterWindow()
        self._diagnostics = DiagnosticsPublisher(self, self._health)
        self._pub = self.create_publisher(Float64MultiArray, itf.TOPIC_ESTIMATE,
                                          QOS[itf.TOPIC_ESTIMATE])
        self.create_subscription(Float64MultiArray, itf.TOPIC_MEASUREMENT,
                                 self._on_measurement, QOS[itf.TOPIC_MEASUREMENT])
        self._fields = [*itf.ESTIMATE_FIELDS,
                        *(f'z{i + 1}' for i in range(self.estimator.encoder.latent))]

    def _on_measurement(self, msg: Float64MultiArray) -> None:
        fault = itf.counted_fault(msg.data, itf.MEASUREMENT_FIELDS)
        if fault is not None:
            self._warn.dropped(itf.TOPIC_MEASUREMENT, fault)
            return
        round_trip = int(msg.data[0])
        self._last_measurement = time.monotonic()
        started = time.perf_counter()
        measurement = np.array(msg.data[1:7], float)
        surrogate, latent = self.estimator.update(measurement)
        if not (np.isfinite(surrogate) and np.isfinite(latent).all()):
            self._warn('nonfinite', f'estimate at round trip {round_trip} is not finite; '
                       'not published')
            return
        latency_ms = self._latency_ms = 1e3 * (time.perf_counter() - started)
        self._pub.publish(vector_message(self._fields,
                                         [round_trip, surrogate, latency_ms, *latent]))
        self.published += 1

    def _health(self, findings: Findings, now: float) -> Health:
        findings.values.update(estimates_published=self.published,
                               latency_ms=self._latency_ms)
        findings.new_drops(self._drops, self._warn)
        findings.input(itf.TOPIC_MEASUREMENT, self._last_measurement,
                       self._diagnostics.started, now, silent_level=WARN)
        return findings.health(f'{self.published} estimates published')

    def stop(self) -> None:
        """Log what was published."""
        self.get_logger().info(f'published {self.published} estimates')


def main(args: list[str] | None = None) -> None:
    sys.exit(params.run_node(VAEEstimatorNode, args))


if __name__ == '__main__':
    main()

"""Everything that makes data and models (numpy, torch; no rclpy): the steady-state sweep,
the oracle envelope and its searches, the drift trajectories, the baseline tables, the
MP-RNN's training, one module per ``dlmpc-train`` stage, and the model card. Nothing here
runs at control time; the controllers load what it writes (:mod:`dlmpc_ros.learning`)."""

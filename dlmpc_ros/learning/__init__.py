"""Learning core (torch, no rclpy): data generation, VAE, K-to-angles map, MP-RNN."""

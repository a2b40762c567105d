"""Examples that use the package as a user would (docs/controllers.md)."""

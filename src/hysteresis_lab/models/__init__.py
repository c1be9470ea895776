"""Model registry (entry points) and the built-in architectures."""

"""TorchRL environments: the mid-level primitive environment."""

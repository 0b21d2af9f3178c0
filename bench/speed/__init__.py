"""Latency and throughput: the runtime, one step on every backend, the hardware floor."""

"""mogo.bench: measurements that print tables. quality/ needs only the runtime (onnxruntime);
speed/ and training/ also use export/ and torch."""

"""The data path inside the netapp: scheduling (per-robot queues, round robin), lanes (batches on the inference
threads), delivery (result messages to waiters, sinks or polling) and the state keeper of stateful processors."""

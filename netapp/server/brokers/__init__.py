"""The netapp's ends of the broker channel (docs/broker.md); the protocols themselves are `netapp.broker`'s.

`netapp serve --publish URL`: every result, of every robot session and every camera, to brokers: the observer the
dataplane tells of each result (`observer`), the command line (`args`) and the metrics (`metrics`).
"""

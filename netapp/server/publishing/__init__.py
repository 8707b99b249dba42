"""`netapp serve --publish URL`: every result, of every robot session and every camera, to brokers
(docs/broker.md). The sending is `netapp.broker`'s; here are the netapp's ends of it: the observer the dataplane
tells of each result (`observer`), the command line (`args`) and the metrics (`metrics`)."""

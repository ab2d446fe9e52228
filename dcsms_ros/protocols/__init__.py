"""Node protocols as plain state machines: no rclpy, no DDS, no clock of their own.

Each module holds one protocol of the graph; a node feeds it what arrives (stamps, values, the
current monotonic time in s) and does what it answers (publish, retransmit, count a fault).
Tests drive them with fake clocks and messages (``test/protocols``).

* :mod:`.barrier` - lockstep barrier of the plant: wait for every due participant's answer to
  sample k, with timeouts, *absent* after repeated misses, retransmission, and a hold before a
  chosen sample (mode schedules);
* :mod:`.pacer` - real-time pacer of the plant (deadlines, overruns), the held inputs that
  go stale, and the publication times an answer's age counts from;
* :mod:`.responder` - per-sample answers keyed by stamp (a repeat gets the cached answer, an
  older stamp is dropped);
* :mod:`.gate` - the first-sample gate (hold the first lockstep answer until every reader
  matched, with a timeout).
"""

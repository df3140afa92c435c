"""The radio profile (docs/PROTOCOL.md §1-§8): frames and messages, the master
(the console's end) and the slave (the ROV's), version 2's chain and wrappers,
a recording's replay, and the simulated-time link the tests and benches use."""

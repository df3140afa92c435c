"""Names vulture cannot see used (`.ci/run` passes this file to vulture with the project).

Each line is a name something outside this code reads or calls: a framework
(FastAPI's response models and routes, pydantic, asyncio's protocol methods,
pytest's hooks and marks, viser's and pyserial's and pymavlink's attributes),
the JSON a client reads (models' fields), or a counter kept for diagnostics (the
stats dataclasses the link and the node expose).  Made with `vulture
--make-whitelist` after the dead code it found was removed; a name added here
needs the same reason.
"""
# ruff: noqa
_.required  # unused attribute (rovlink/cli.py:74)
_.robust_parsing  # unused attribute (console/gcs.py:228)
_.seabed_node  # unused attribute (console/scene/app.py:296)
_.rov_mesh_node  # unused attribute (console/scene/app.py:312)
_.ghost_mesh_node  # unused attribute (console/scene/app.py:318)
_.up_direction  # unused attribute (console/scene/app.py:855)
_.disabled  # unused attribute (console/scene/panel.py:185)
_.disabled  # unused attribute (console/scene/panel.py:319)
_.disabled  # unused attribute (console/scene/panel.py:324)
_.capture_signals  # unused method (console/web/app.py:165)
_.should_exit  # unused attribute (console/web/app.py:192)
forward_mps  # unused variable (console/web/models.py:118)
right_mps  # unused variable (console/web/models.py:119)
down_mps  # unused variable (console/web/models.py:120)
yaw_dps  # unused variable (console/web/models.py:121)
uncertainty_m  # unused variable (console/web/models.py:138)
not_before_wall  # unused variable (console/web/models.py:161)
not_after_wall  # unused variable (console/web/models.py:162)
received_wall  # unused variable (console/web/models.py:174)
since_reply_s  # unused variable (console/web/models.py:196)
failsafe_inferred  # unused variable (console/web/models.py:199)
failsafe_inferred_at  # unused variable (console/web/models.py:200)
failsafe_inferred_since  # unused variable (console/web/models.py:201)
poll_rate_hz  # unused variable (console/web/models.py:203)
reply_rate_hz  # unused variable (console/web/models.py:204)
bytes_per_s  # unused variable (console/web/models.py:212)
auth_alert  # unused variable (console/web/models.py:224)
link_up  # unused variable (console/web/models.py:225)
transport_up  # unused variable (console/web/models.py:226)
t_queued  # unused variable (console/web/models.py:245)
holder_kind  # unused variable (console/web/models.py:259)
held_for_s  # unused variable (console/web/models.py:260)
you  # unused variable (console/web/models.py:261)
unattended_warning  # unused variable (console/web/models.py:264)
unattended_s  # a field of the control status model (console/web/models.py)
centre_to_drive  # unused variable (console/web/models.py:266)
stop_key  # unused variable (console/web/models.py:325)
stop_key_anywhere  # unused variable (console/web/models.py:326)
key_gain  # unused variable (console/web/models.py:327)
default_target  # unused variable (console/web/models.py:332)
default_roi_shift  # unused variable (console/web/models.py:333)
go_to_mode  # unused variable (console/web/models.py:334)
available  # unused variable (console/web/routers/replay.py:27)
speeds  # unused variable (console/web/routers/replay.py:34)
min_speed  # unused variable (console/web/routers/replay.py:35)
max_speed  # unused variable (console/web/routers/replay.py:36)
_.required  # unused attribute (debt/cli.py:58)
images_started  # unused variable (link/radio/master.py:233)
_.images_started  # unused attribute (link/radio/master.py:511)
restarts_seen  # unused variable (link/radio/secure.py:119)
_.restarts_seen  # unused attribute (link/radio/secure.py:340)
orders_abandoned  # unused variable (link/radio/slave.py:209)
invalid_wishes  # unused variable (link/radio/slave.py:210)
velocity_lapses  # unused variable (link/radio/slave.py:211)
trunk_bytes_sent  # unused variable (link/radio/slave.py:212)
_.velocity_lapses  # unused attribute (link/radio/slave.py:348)
_.trunk_bytes_sent  # unused attribute (link/radio/slave.py:410)
_.invalid_wishes  # unused attribute (link/radio/slave.py:420)
_.orders_abandoned  # unused attribute (link/radio/slave.py:526)
failures  # unused variable (link/transports/transport.py:45)
frames_sent  # unused variable (link/transports/transport.py:46)
_.failures  # unused attribute (link/transports/transport.py:174)
_.frames_sent  # unused attribute (link/transports/transport.py:194)
_.datagram_received  # unused method (link/transports/transport.py:259)
_.error_received  # unused method (link/transports/transport.py:276)
_.connection_lost  # unused method (link/transports/transport.py:281)
_.baudrate  # unused attribute (link/transports/transport.py:314)
_.write_timeout  # unused attribute (link/transports/transport.py:316)
_.handle_eof  # unused attribute (rov/mavurl.py:128)
_.handle_disconnect  # unused attribute (rov/mavurl.py:129)
images_prefetched_used  # unused variable (rov/node.py:84)
encode_failures  # unused variable (rov/node.py:85)
goto_failed  # unused variable (rov/node.py:87)
last_encode_s  # unused variable (rov/node.py:90)
_.goto_failed  # unused attribute (rov/node.py:200)
_.images_prefetched_used  # unused attribute (rov/node.py:338)
_.encode_failures  # unused attribute (rov/node.py:352)
_.last_encode_s  # unused attribute (rov/node.py:386)
vx_mps  # unused variable (rov/telemetry.py:44)
vy_mps  # unused variable (rov/telemetry.py:45)
vz_mps  # unused variable (rov/telemetry.py:46)
position_age_s  # unused variable (rov/telemetry.py:54)
updated_s  # unused variable (rov/telemetry.py:59)
pytest_collection_modifyitems  # unused function (tests/conftest.py:20)
pytestmark  # unused variable (tests/console/test_browser.py:18)
pytestmark  # unused variable (tests/console/test_cockpit.py:33)
pytestmark  # unused variable (tests/console/test_demo.py:31)
pytestmark  # unused variable (tests/console/test_gamepad.py:25)
pytestmark  # unused variable (tests/console/test_gcs.py:24)
pytestmark  # unused variable (tests/console/test_restarts.py:32)
pytestmark  # unused variable (tests/console/test_truth.py:23)
pytestmark  # unused variable (tests/test_packaging.py:30)
cleared_wall  # a field of LogEntry (console/session/state.py): the page reads it
port_error  # a field of LinkState (console/session/state.py): the page reads it
degraded_reason  # a field of LinkState (console/session/state.py): the page reads it
degraded_short  # a field of LinkState (console/session/state.py): the page reads it
link_process_pid
# The acoustic profile's counters, kept for diagnostics (link/acoustic.py Counters) and
# what its machines and its bench expose to their callers.
_.stale_syncs  # unused attribute (link/acoustic.py)
_.data_packets  # unused attribute (link/acoustic.py)
_.data_ignored  # unused attribute (link/acoustic.py)
_.thumbnails_verified  # unused attribute (link/acoustic.py)
_.orders_taken  # unused attribute (link/acoustic.py)
_.orders_stale  # unused attribute (link/acoustic.py)
_.stops_taken  # unused attribute (link/acoustic.py)
_.unpaired  # unused attribute (link/acoustic.py)
_.last_status  # unused attribute (link/acoustic.py: AcousticOperator's last STATUS, for callers)
_.up_s  # unused attribute (link/acoustic/bench.py)
_.report_every_s  # a Capabilities field, served in GET /api/config (console/session/contract.py)
_.next_report_in_s  # response model fields (console/session/state.py), read by the page
link_process_pid  # a field of LinkState (console/session/state.py): which process owns the link port, for a script or a test
link_process  # a field of LinkState (console/session/state.py): the page reads it
link_process_reason  # a field of LinkState (console/session/state.py): the page reads it
reports_lost  # a field of LinkState (console/session/state.py): the page and the scene's panel read it
bad_frames  # a field of LinkState (console/session/state.py): the page and the scene's panel read it
record_bytes  # §11's object events (link/radio/events.py, link/acoustic/events.py): the console shows bytes per object
record_hex  # §11's events of a record out of range: the console's log line shows it
class_  # WorldState's object fields (console/session/state.py): the page and GET /api/world read them
first_t  # the same
updated_t  # the same
altitude_age_s  # the same
altitude_stale  # the same
seabed_unknown_why  # the same

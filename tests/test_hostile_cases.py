"""Issue 27's cases, each with the regression test that holds it (a reviewer's checklist).

The second hostile round found 22 cases where a promise broke; the issue's text lists them
in five groups, and this list splits them one command or one input per case, each with its
tests (``->``). Every test named here runs the real CLI (in-process through
``bench.cli.main`` or as a subprocess with a hang guard) and asserts the exit code, the one
``bench: error:`` line and, where a file could be destroyed, its bytes before and after.
The test below fails when a case names a test that no longer exists.

1   `bench replay X.log --csv X.log` overwrote the log
    -> test_hostile_paths::test_replay_output_onto_its_input_is_refused
2   `bench replay X.mcap --parquet X.mcap`: SIGBUS, 4 bytes left
    -> test_hostile_paths::test_replay_output_onto_its_input_is_refused
2a  the same by a hard link, a symlink, a relative name; `--config` as output
    -> test_hostile_paths::test_replay_output_onto_its_input_by_another_name
    -> test_hostile_paths::test_replay_config_is_an_input_too
3   `bench run --emulate S.toml --mcap S.toml` (or `--csv S.toml`)
    -> test_hostile_paths::test_run_output_onto_its_scenario_is_refused
4   `bench emulate S.toml --calibration-out S.toml` (and `--out`, `--truth`)
    -> test_hostile_paths::test_emulate_output_onto_its_scenario_is_refused
5   `bench log export M.mcap --candump M.mcap`: SIGBUS
    -> test_hostile_paths::test_log_export_onto_its_input_is_refused
5a  the other commands' outputs onto their inputs (calibrate, accept, tui, demo, fleet)
    -> test_hostile_paths::test_calibrate_onto_its_log_is_refused
    -> test_hostile_paths::test_accept_into_the_folder_of_its_plan_is_refused
    -> test_hostile_paths::test_tui_replay_recording_onto_the_log_replayed_is_refused
    -> test_hostile_paths::test_demo_recording_onto_its_scenario_is_refused
    -> test_hostile_paths::test_fleet_index_onto_its_config_is_refused
6   `bench run --mcap F --csv F` left a CSV and no log
    -> test_hostile_paths::test_run_mcap_and_csv_on_one_path_is_refused
7   `--csv F --parquet F` left a file that was neither
    -> test_hostile_paths::test_replay_csv_and_parquet_on_one_path_is_refused
7a  a failed run leaves no half file under the real name
    -> test_hostile_paths::test_a_failed_replay_keeps_what_the_outputs_held
    -> test_hostile_paths::test_an_interrupted_emulation_leaves_no_half_file
    -> test_hostile_paths::test_a_truth_csv_that_fails_part_way_leaves_the_name_as_it_was
8   an MCAP truncated while replayed: SIGBUS, no message
    -> test_hostile_loss::test_an_mcap_that_shrinks_while_replayed_is_an_error_not_sigbus
    -> test_hostile_loss::test_mcap_reader_reports_a_shrunk_file_at_the_chunk_it_cannot_read
    -> test_hostile_loss::test_a_device_log_that_changes_while_replayed_is_an_error
9   two channels named `/can/frames`: 1 650 of 3 300 frames, `log info` 1 650
    -> test_hostile_loss::test_every_channel_of_can_frames_is_replayed
9a  a channel of another schema on `/can/frames`: read as RawFrames, whole chunks skipped
    -> test_hostile_loss::test_a_foreign_channel_on_can_frames_costs_no_frame_and_is_warned
10  BLF first object size 0xFFFFFFF0: 2 730 of 3 300, no warning
    -> test_hostile_loss::test_blf_whose_first_object_size_is_absurd_loses_nothing_and_says_so
10a a BLF container whose compressed data is damaged: the warning gives the header's count
    -> test_hostile_loss::test_blf_whose_second_container_is_damaged_says_what_the_header_declares
11  UTF-8 BOM before `.trc` (every frame lost), `.asc`, candump (line 1 lost)
    -> test_hostile_loss::test_a_bom_before_a_text_log_loses_no_frame
11a BOM in TOML configs, scenarios, plans, steps files, tilt tables
    -> test_hostile_inputs::test_utf8_bom_config_is_read
    -> test_hostile_loss::test_a_bom_in_a_scenario_and_a_plan_is_read
    -> test_hostile_loss::test_a_bom_in_a_steps_file_and_a_tilt_table_is_read
    -> test_hostile_loss::test_a_bom_scenario_is_recorded_as_toml_reads_it
12  a live CSV deleted, replaced by a folder or a symlink mid-run: exit 0, rows gone
    -> test_hostile_loss::test_a_live_csv_that_disappears_is_a_failure
13  `--config /dev/zero` or a FIFO: replay and fleet wait forever
    -> test_hostile_paths::test_replay_config_that_is_not_a_file_is_refused
    -> test_hostile_paths::test_fleet_config_that_is_not_a_file_is_refused
14  `bench emulate /dev/zero` and `bench accept /dev/zero` wait forever
    -> test_hostile_paths::test_emulate_and_accept_of_a_device_are_refused
15  a plan whose `scenario` is `/dev/zero` or a FIFO (and a FIFO `--steps`)
    -> test_hostile_paths::test_plan_whose_scenario_is_not_a_file_is_refused
    -> test_hostile_paths::test_steps_file_that_is_a_fifo_is_refused
    -> test_hostile_paths::test_a_reference_table_that_is_a_fifo_is_named_for_what_it_is
15a a FIFO or `/dev/zero` as the log replayed
    -> test_hostile_inputs::test_fifo_log_is_refused
    -> test_hostile_inputs::test_dev_zero_log_is_refused
    -> test_hostile_paths::test_a_defaults_file_that_is_not_a_file_is_an_error
15b a FIFO or `/dev/zero` given to `bench log info`/`log export` (an MCAP opener of its own)
    -> test_hostile_paths::test_an_mcap_log_that_is_a_fifo_is_refused
    -> test_hostile_paths::test_log_info_and_export_of_a_device_are_refused
16  a FIFO among `bench fleet`'s logs waits forever
    -> test_hostile_loss::test_fleet_rows_of_logs_without_frames_are_errors
17  a Foxglove client that subscribes and never reads holds `--duration 10` for minutes;
    SIGTERM does not end it
    -> test_hostile_viewer::test_a_viewer_that_never_reads_does_not_hold_the_run_past_its_duration
    -> test_hostile_viewer::test_sigterm_ends_a_run_whose_viewer_never_reads
17a per client a bounded outbox that drops and counts, a send timeout that lets it go
    -> test_hostile_viewer::test_the_front_drops_and_counts_for_a_viewer_that_never_reads
    -> test_hostile_viewer::test_a_run_says_what_a_stalled_viewer_cost
    -> test_hostile_viewer::test_a_viewer_on_a_slow_link_is_dropped_for_not_disconnected
    -> test_hostile_viewer::test_a_stalled_client_of_the_sdks_own_port_does_not_hold_the_close
17b a peer that opens connections and says nothing, or very many of them
    -> test_hostile_viewer::test_a_connection_that_never_sends_its_request_is_closed
    -> test_hostile_viewer::test_connections_beyond_the_limit_are_refused_and_counted
18  `bench fleet --workers 100000` grows memory without answering
    -> test_hostile_records::test_bad_fleet_options_are_one_line
19  random bytes named `.log`, a cut `.mcap` with 0 frames: "replayed", exit 0
    -> test_hostile_loss::test_replay_of_a_log_without_frames_is_an_error
    -> test_hostile_loss::test_log_export_of_an_mcap_without_frames_is_an_error
    -> test_hostile_loss::test_fleet_rows_of_logs_without_frames_are_errors
20  SIGTERM during `bench accept --realtime` leaves no junit/record/report
    -> test_hostile_records::test_sigterm_during_a_realtime_acceptance_writes_the_records
21  `--station` with a control character: junit.xml not well-formed
    -> test_hostile_records::test_a_control_character_for_the_record_is_refused
    -> test_hostile_records::test_junit_escapes_control_characters_it_is_handed
22  `--compare` on a file without results: "DIFFERENT (0 of 0 rows differ)"
    -> test_hostile_records::test_compare_of_a_log_without_recorded_results_is_an_error
23  `bench run ... 2>&1 | head -1` stops after 0.2 s of 4, exit 0
    -> test_hostile_records::test_a_closed_status_pipe_does_not_end_the_recording
24  `--scheduler garbage` prints a ValueError traceback
    -> test_hostile_records::test_bad_fleet_options_are_one_line
25  a port in use prints "MCAP log FAILED: ws:/..." with `--no-log`
    -> test_hostile_records::test_a_foxglove_port_in_use_is_not_an_mcap_failure
26  a `--no-plots` run into a reused folder keeps the previous plan's PNGs
    -> test_hostile_records::test_a_report_without_plots_keeps_no_plots_of_an_earlier_run

What each command does with a clashing path, a changing file and a slow viewer:
docs/DEVICES.md ("A command's files: clashes, files that change, viewers that stall", one
row per command), docs/MCAP.md (the live stream: "A viewer that stalls never holds the
run") and docs/TUI.md (bench tui and demo).
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

TESTS = Path(__file__).resolve().parent


def _named() -> list[tuple[str, str]]:
    assert __doc__ is not None
    cases = re.findall(r"^(\d+)a? ", __doc__, re.MULTILINE)
    assert len(set(cases)) >= 22, cases  # the 22, its lists split one per row
    return re.findall(r"^    -> (test_\w+)::(test_\w+)$", __doc__, re.MULTILINE)


def test_every_case_names_a_test_that_exists() -> None:
    names = _named()
    assert names
    missing = []
    for module, name in names:
        tree = ast.parse((TESTS / f"{module}.py").read_text())
        defined = {n.name for n in tree.body if isinstance(n, ast.FunctionDef)}
        if name not in defined:
            missing.append(f"{module}::{name}")
    assert not missing, missing

"""The daemon's statistics as text: one line per output and per device, from the record
`Daemon.stats_record()` builds (the same record `run --stats-format json` prints whole).

Each counter's label lives here once; a key missing from a record (an output without RX, a
SUMD output without service frames) is left out of its line.
"""

from __future__ import annotations

from typing import Any

# record key -> how the text line shows it, in line order
OUTPUT_FIELDS: tuple[tuple[str, str], ...] = (
    ("writes", "writes {}"),
    ("ticks", "ticks {}"),
    ("late_ticks", "late {}"),
    ("missed_ticks", "missed {}"),
    ("period_p99_error_ms", "p99 |period error| {:.3f} ms"),
    ("tick_p99_ms", "p99 tick {:.3f} ms"),
    ("bytes_written", "bytes {}"),
    ("queue_full_skips", "queue-full skips {}"),
    ("write_timeouts", "write timeouts {}"),
    ("short_writes", "short writes {}"),
    ("stalls", "stalls {}"),
    ("stale_flushes", "stale flushes {}"),
    ("line_losses", "line losses {}"),
    ("tick_errors", "tick errors {}"),
    ("input_age_ms", "input age p50 {p50:.2f} / p99 {p99:.2f} / max {max:.2f} ms"),
    ("data_frames", "data frames {}"),
    ("service_frames", "service frames {}"),
    ("round_robin_deferrals", "round-robin deferrals {}"),
    ("handover_frames", "handover frames {}"),
    ("handovers_cut", "(cut by failsafe {})"),
    ("low_battery_frames", "low battery frames {}"),
    ("rx_bytes", "rx bytes {}"),
    ("rx_skipped", "rx skipped {}"),
    ("rx_crc_failures", "rx crc failures {}"),
    ("rx_requests", "requests {}"),
    ("rx_requests_dropped", "(dropped {})"),
    ("rx_dropped_bytes", "rx bytes dropped (faster than the line) {}"),
    ("module", "{}"),
    ("frames_withheld", "frames withheld (failsafe) {}"),
    ("module_rx_frames", "rx frames {}"),
    ("module_rx_crc_failures", "rx crc failures {}"),
    ("module_rx_skipped", "rx skipped {}"),
    ("module_rx_reads_dropped", "rx reads dropped (queue full) {}"),
    ("timing_corrections", "timing corrections {}"),
    ("timing_corrections_ignored", "(ignored {})"),
    ("mavlink_message", "{}"),
    ("control_messages", "control messages {}"),
    ("releases", "releases {}"),
    ("silent_failsafe_ticks", "silent failsafe ticks {}"),
    ("heartbeats_sent", "heartbeats {}"),
    ("far_end_messages", "far end: messages {}"),
    ("far_end_heartbeats", "heartbeats {}"),
    ("far_end_heartbeat_from", "(last from {})"),
    ("far_end_skipped", "bytes skipped {}"),
    ("far_end_bad_signatures", "bad signatures {}"),
    ("actions_fired", "actions: fired {}"),
    ("actions_sent", "commands sent {}"),
    ("actions_acked", "acked {}"),
    ("actions_unanswered", "unanswered {}"),
    ("actions_refused", "refused {}"),
    ("actions_last", "last: {}"),
    ("udp_peer", "peer {}"),
    ("datagrams_from_peer", "datagrams from it {}"),
    ("datagrams_from_others", "from others ignored {}"),
    ("datagrams_not_allowed", "not allowed {}"),
)


def output_line(record: dict[str, Any]) -> str:
    fields = [
        _field(text, record[key]) for key, text in OUTPUT_FIELDS if record.get(key) is not None
    ]
    return f"{record['name']} {record['url']}: " + ", ".join(fields)


def _field(text: str, value: Any) -> str:
    """A counter (`text` with one place), or a record of named figures (`{p50}`...);
    None, a figure not measured yet, is left out by its caller."""
    return text.format(**value) if isinstance(value, dict) else text.format(value)


def device_line(record: dict[str, Any]) -> str:
    age = record["last_report_age_s"]
    line = (
        f"device {record['name']} ({record['port_path']}): "
        f"{record['reports']} reports ({record['reports_per_s']:.1f}/s avg), "
        f"bad {record['bad_reports']}, last report "
        + ("never" if age is None else f"{age:.2f} s ago")
    )
    if "backend_busy_ms" in record:
        line += f", backend busy {record['backend_busy_ms']:.1f} ms"
    return line


def missing_line(record: dict[str, Any]) -> str:
    where = f"; {record['where']}" if record.get("where") else ""
    return (
        f"missing: node {record['node_id']} config entry {record['entry']!r} "
        f"({record['match']}{where}): no device plugged, the node sends failsafe"
    )


def stats_lines(record: dict[str, Any]) -> list[str]:
    return [
        *map(output_line, record["outputs"]),
        *map(device_line, record["devices"]),
        *map(missing_line, record.get("missing_devices", [])),
    ]

#!/bin/sh
# Static checks of the systemd unit, udev rules and sysusers file (no running systemd needed):
#   systemd-analyze verify    (on a copy whose ExecStart points at /bin/true: verify insists the
#                              binary exists, and /opt/usb2rc is not installed in CI; the copy
#                              differs from the shipped unit in that one path, checked below)
#   systemd-analyze security  (offline; fails above MAX_EXPOSURE)
#   the network drop-in      (what `install-system` writes for config/mavlink.yaml's UDP
#                              output: verify clean and exposure at most MAX_NETWORK_EXPOSURE
#                              with it beside the unit)
#   systemd-sysusers --root   (creates the user in a scratch root)
#   udevadm verify            (systemd >= 254; skipped with a note on older udev)
#   grep                      (RestartPreventExitStatus=2: a config error must not restart in a
#                              loop; Documentation= names the notes install-system writes;
#                              RuntimeDirectory=usb2rc: the status socket's /run/usb2rc)
#   the web unit              (usb2rc-web.service, `install-system --web`: verify clean,
#                              exposure at most MAX_WEB_EXPOSURE)
set -eu

MAX_EXPOSURE=${MAX_EXPOSURE:-1.2}
MAX_NETWORK_EXPOSURE=${MAX_NETWORK_EXPOSURE:-2.0}
MAX_WEB_EXPOSURE=${MAX_WEB_EXPOSURE:-1.2}
here=$(cd "$(dirname "$0")/.." && pwd)
python=${PYTHON:-$here/.venv/bin/python}
[ -x "$python" ] || python=python3
system="$here/usb2rc/data/system"  # package data: the wheel ships these (usb2rc install-system)
unit="$system/usb2rc.service"
web_unit="$system/usb2rc-web.service"
rules="$system/70-usb2rc.rules"
sysusers="$system/usb2rc.sysusers"

if ! command -v systemd-analyze >/dev/null 2>&1; then
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq systemd >/dev/null
fi

tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

echo "== unit directives"
grep -qx 'RestartPreventExitStatus=2' "$unit" || { echo "no RestartPreventExitStatus=2" >&2; exit 1; }
grep -qx 'Documentation=file:/usr/share/doc/usb2rc/SERVICE.md' "$unit" || {
    echo "no Documentation= naming the installed SERVICE.md" >&2; exit 1; }
grep -qx 'RuntimeDirectory=usb2rc' "$unit" || { echo "no RuntimeDirectory=usb2rc" >&2; exit 1; }
for u in "$unit" "$web_unit"; do
    grep -q '^RestrictAddressFamilies=.*AF_UNIX' "$u" || { echo "$u: no AF_UNIX" >&2; exit 1; }
done
grep -qx 'RestartPreventExitStatus=2' "$web_unit" || { echo "web: no RestartPreventExitStatus=2" >&2; exit 1; }
echo "present"

# verify_copy UNIT: a copy of UNIT in $tmp whose ExecStart runs /bin/true (only that line
# differs), verified clean.
verify_copy() {
    copy="$tmp/$(basename "$1")"
    sed 's|^ExecStart=/opt/usb2rc/venv/bin/usb2rc |ExecStart=/bin/true |' "$1" >"$copy"
    changed=$(diff "$1" "$copy" | grep -c '^>' || true)
    [ "$changed" -eq 1 ] || { echo "$1: expected exactly the ExecStart line to change" >&2; exit 1; }
    out=$(systemd-analyze verify "$copy" 2>&1) || { echo "$out" >&2; exit 1; }
    [ -z "$out" ] || { echo "$out" >&2; echo "verify printed warnings" >&2; exit 1; }
    echo "clean"
}

echo "== systemd-analyze verify"
verify_copy "$unit"

# exposure UNIT MAX: the unit's offline exposure (drop-ins beside it included), failing above MAX.
exposure() {
    report=$(systemd-analyze security --offline=true --no-pager "$1" 2>&1) || true
    level=$(printf '%s\n' "$report" | sed -n 's/.*Overall exposure level for [^:]*: \([0-9.]*\).*/\1/p')
    [ -n "$level" ] || { echo "$report" >&2; echo "no exposure level found" >&2; exit 1; }
    echo "exposure $level (max $2)"
    awk -v e="$level" -v m="$2" 'BEGIN { exit !(e <= m) }' || {
        printf '%s\n' "$report" | grep '✗' >&2
        exit 1
    }
}

echo "== systemd-analyze security"
exposure "$unit" "$MAX_EXPOSURE"

echo "== the network drop-in (config/mavlink.yaml: udpout:127.0.0.1)"
mkdir -p "$tmp/usb2rc.service.d"
(cd "$here" && "$python" -m usb2rc install-system --print network.conf \
    --config usb2rc/data/config/mavlink.yaml) >"$tmp/usb2rc.service.d/network.conf"
grep -qx 'IPAddressAllow=127.0.0.1' "$tmp/usb2rc.service.d/network.conf" || {
    cat "$tmp/usb2rc.service.d/network.conf" >&2; echo "no IPAddressAllow=127.0.0.1" >&2; exit 1; }
out=$(systemd-analyze verify "$tmp/usb2rc.service" 2>&1) || { echo "$out" >&2; exit 1; }
[ -z "$out" ] || { echo "$out" >&2; echo "verify printed warnings" >&2; exit 1; }
echo "verify clean"
exposure "$tmp/usb2rc.service" "$MAX_NETWORK_EXPOSURE"

echo "== the web unit (install-system --web)"
verify_copy "$web_unit"
exposure "$web_unit" "$MAX_WEB_EXPOSURE"

echo "== systemd-sysusers"
mkdir -p "$tmp/root/etc"
systemd-sysusers --root="$tmp/root" - <"$sysusers" >/dev/null 2>&1
grep -q '^usb2rc:' "$tmp/root/etc/passwd"
echo "creates usb2rc"

echo "== udevadm verify"
if command -v udevadm >/dev/null 2>&1 && udevadm verify --help >/dev/null 2>&1; then
    udevadm verify "$rules"
    echo "clean"
else
    echo "skipped: udevadm verify needs systemd >= 254 (tests/test_systemd_unit.py lints the rules)"
fi

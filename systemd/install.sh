#!/bin/sh
# Install or remove lunad as a systemd service (Raspberry Pi OS Bookworm, Debian 12).
#
#   sudo sh systemd/install.sh install      # or: sudo make install
#   sudo sh systemd/install.sh uninstall    # or: sudo make uninstall
#
# Needs only what the OS ships: sh, python3 (with its venv module), install(1),
# and systemctl/systemd-sysusers when they are there. Both actions are idempotent:
# run them as often as you like; install again to upgrade.
#
# What install puts where (PREFIX=/opt/lunad):
#   $PREFIX/venv/                      python3 -m venv, lunad and its dependencies
#   $PREFIX/share/                     raspberry-pi.md, security.md, 99-tfluna.rules (udev example)
#   /etc/systemd/system/lunad@.service the unit (ExecStart under $PREFIX)
#   /etc/sysusers.d/lunad.conf         the "lunad" system user (created right away)
#   /etc/modules-load.d/lunad.conf     USB-serial and i2c-dev drivers at boot
#   /etc/lunad/lunad.toml.example      every config key, commented (refreshed)
#   /etc/lunad/curve/                  CURVE keys for TCP endpoints (docs/security.md):
#                                      server.key, server.key_secret (lunad, 0600),
#                                      made once on a real install (not with DESTDIR),
#                                      and clients/ for the client public keys
# It never touches /etc/lunad/*.toml: your sensor configs are yours, and keeps
# existing keys: clients pin the server's public key.
#
# uninstall stops and disables every lunad@ instance and removes all of the
# above, but keeps /etc/lunad/*.toml (PURGE=1 removes /etc/lunad too) and the
# "lunad" user (removing a user leaves files owned by a recyclable id).
#
# Environment:
#   DESTDIR   stage into this root instead of /: no systemctl, no sysusers, no
#             root needed; venv scripts are rewritten to run from $PREFIX later.
#   PREFIX    where the venv and shared files go (default /opt/lunad)
#   PYTHON    the interpreter for the venv (default python3, needs 3.11+)
#   PURGE=1   uninstall also removes /etc/lunad with your configs
#   LUNAD_INSTALL_SKIP_PIP=1   skip the venv and pip step (tests)
#   LUNAD_PIP_ARGS             extra pip arguments, e.g. "--no-index --find-links DIR"
#   LUNAD_PACKAGE              what pip installs (default: this checkout)
set -eu

action=${1:-install}
DESTDIR=${DESTDIR:-}
PREFIX=${PREFIX:-/opt/lunad}
PYTHON=${PYTHON:-python3}
SRC=$(cd "$(dirname "$0")/.." && pwd)
ROOT=$DESTDIR
VENV=$ROOT$PREFIX/venv
UNIT_DIR=$ROOT/etc/systemd/system
UNIT=$UNIT_DIR/lunad@.service
SYSUSERS=$ROOT/etc/sysusers.d/lunad.conf
MODULES=$ROOT/etc/modules-load.d/lunad.conf
CONF_DIR=$ROOT/etc/lunad
SHARE=$ROOT$PREFIX/share
MARKER=$ROOT$PREFIX/.lunad-install

say() { printf 'lunad: %s\n' "$*"; }
die() { printf 'lunad: %s\n' "$*" >&2; exit 1; }

case $PREFIX in
/*) ;;
*) die "PREFIX must be an absolute path, got '$PREFIX'" ;;
esac

# Real installs only: systemd is there and running as PID 1.
live_systemd() {
    [ -z "$DESTDIR" ] && [ -d /run/systemd/system ] && command -v systemctl >/dev/null 2>&1
}

need_root() {
    if [ -z "$DESTDIR" ] && [ "$(id -u)" -ne 0 ]; then
        die "$action writes to /etc and $PREFIX: run it with sudo (or set DESTDIR to stage)"
    fi
}

install_venv() {
    if [ "${LUNAD_INSTALL_SKIP_PIP:-0}" = 1 ]; then
        say "skipping the venv and pip step (LUNAD_INSTALL_SKIP_PIP=1)"
        return
    fi
    "$PYTHON" -c 'import sys; sys.exit(sys.version_info < (3, 11))' ||
        die "$PYTHON is older than 3.11 (Raspberry Pi OS Bookworm has 3.11)"
    "$PYTHON" -c 'import ensurepip, venv' 2>/dev/null ||
        die "$PYTHON cannot create a venv: sudo apt install python3-venv"
    if [ ! -x "$VENV/bin/python" ]; then
        say "creating $PREFIX/venv"
        "$PYTHON" -m venv "$VENV"
    fi
    pkg=${LUNAD_PACKAGE:-}
    tmp=
    if [ -z "$pkg" ]; then
        # Build from a copy so that a root-run pip leaves no build/ or egg-info
        # owned by root in the user's checkout.
        tmp=$(mktemp -d)
        cp -R "$SRC/pyproject.toml" "$SRC/README.md" "$SRC/protocol" "$SRC/filters" \
            "$SRC/sim" "$SRC/daemon" "$tmp/"
        pkg=$tmp
    fi
    say "installing lunad into $PREFIX/venv (pip; this downloads the dependencies)"
    # shellcheck disable=SC2086  # LUNAD_PIP_ARGS is a list of words on purpose
    if ! "$VENV/bin/python" -m pip install --disable-pip-version-check --quiet \
        ${LUNAD_PIP_ARGS:-} "$pkg"; then
        if [ -n "$tmp" ]; then rm -rf "$tmp"; fi
        die "pip install failed (see above)"
    fi
    if [ -n "$tmp" ]; then rm -rf "$tmp"; fi
    if [ -n "$DESTDIR" ]; then
        # Scripts in venv/bin name their interpreter by absolute path: make them
        # name $PREFIX, where the staged tree will live.
        "$PYTHON" - "$VENV" "$DESTDIR$PREFIX/venv" "$PREFIX/venv" <<'EOF'
import sys
from pathlib import Path

venv, staged, final = Path(sys.argv[1]), sys.argv[2].encode(), sys.argv[3].encode()
for path in [*(venv / "bin").iterdir(), venv / "pyvenv.cfg"]:
    if path.is_symlink() or not path.is_file():
        continue
    data = path.read_bytes()
    if b"\0" not in data[:1024] and staged in data:
        path.write_bytes(data.replace(staged, final))
EOF
    fi
}

install_curve() {
    curve=$CONF_DIR/curve
    install -d -m 0755 "$curve" "$curve/clients"
    # A staged tree may be copied to many machines: each must make its own pair.
    [ -z "$DESTDIR" ] || return 0
    if [ -e "$curve/server.key_secret" ] || [ -e "$curve/server.key" ]; then
        return 0
    fi
    if [ ! -x "$VENV/bin/lunad" ]; then
        say "not making CURVE keys: $PREFIX/venv/bin/lunad is missing"
        return 0
    fi
    if ! out=$("$VENV/bin/lunad" keys server "$curve"); then
        say "could not make the CURVE server keys in /etc/lunad/curve (see above)"
        return 0
    fi
    chown lunad:lunad "$curve/server.key_secret"
    key=$(printf '%s\n' "$out" | sed -n 's/^public key: //p')
    say "made the CURVE server key pair in /etc/lunad/curve (public key $key)"
}

do_install() {
    need_root
    # PREFIX is ours alone: uninstall removes what is in it. A directory that exists,
    # holds files and has no marker (/usr/local, say) belongs to someone else.
    if [ -d "$ROOT$PREFIX" ] && [ ! -f "$MARKER" ] && [ -n "$(ls -A "$ROOT$PREFIX")" ]; then
        die "$PREFIX already holds other files; lunad needs a directory of its own (the default /opt/lunad, or a new one)"
    fi
    install_venv
    install -d -m 0755 "$UNIT_DIR" "$ROOT/etc/sysusers.d" "$ROOT/etc/modules-load.d" \
        "$CONF_DIR" "$SHARE"
    # The unit names /opt/lunad; point it at PREFIX. Written to a temporary file
    # first so that a failure never leaves half a unit behind.
    tmpunit=$(mktemp)
    sed "s#/opt/lunad/#$PREFIX/#g" "$SRC/systemd/lunad@.service" >"$tmpunit"
    install -m 0644 "$tmpunit" "$UNIT"
    rm -f "$tmpunit"
    install -m 0644 "$SRC/systemd/lunad.sysusers" "$SYSUSERS"
    install -m 0644 "$SRC/systemd/lunad-modules.conf" "$MODULES"
    install -m 0644 "$SRC/systemd/lunad.toml.example" "$CONF_DIR/lunad.toml.example"
    install -m 0644 "$SRC/systemd/99-tfluna.rules" "$SHARE/99-tfluna.rules"
    install -m 0644 "$SRC/docs/raspberry-pi.md" "$SHARE/raspberry-pi.md"
    install -m 0644 "$SRC/docs/security.md" "$SHARE/security.md"
    printf 'lunad installed from %s\n' "$SRC" >"$MARKER"
    chmod 0644 "$MARKER"

    if [ -z "$DESTDIR" ]; then
        if command -v systemd-sysusers >/dev/null 2>&1; then
            systemd-sysusers "$SYSUSERS"
        else
            die "systemd-sysusers is missing: cannot create the lunad user"
        fi
    fi
    install_curve
    if live_systemd; then
        systemctl start systemd-modules-load.service || true
        systemctl daemon-reload
        # An upgrade takes effect in running instances; stopped ones stay stopped.
        systemctl try-restart 'lunad@*.service' || true
    fi

    say "installed under ${DESTDIR:-/}: $PREFIX/venv, /etc/systemd/system/lunad@.service"
    cat <<EOF

Next, for a sensor called "front" (one config file and one instance per sensor):

  sudo cp /etc/lunad/lunad.toml.example /etc/lunad/front.toml   # then edit [sensor] name
                                                                # and [source] device
  sudo systemctl enable --now lunad@front

It publishes on ipc:///run/lunad/front.sock ([publish] endpoint: another instance
needs its own, ipc:///run/lunad/<instance>.sock). Only user and group lunad may
connect: add the user your robot code runs as to the group (it takes effect at
its next login):

  sudo usermod -aG lunad <user>

To publish on a LAN instead, encrypted and for listed clients only (CURVE), see
$PREFIX/share/security.md: the server keys are in /etc/lunad/curve.

Check it with: systemctl status lunad@front ; journalctl -u lunad@front -f
Guide: $PREFIX/share/raspberry-pi.md
EOF
}

do_uninstall() {
    need_root
    if live_systemd; then
        systemctl stop 'lunad@*.service' || true
    fi
    # Enabled instances are symlinks in *.wants/ directories next to the unit.
    for link in "$UNIT_DIR"/*.wants/lunad@*.service; do
        [ -L "$link" ] || continue
        if live_systemd; then
            systemctl disable "$(basename "$link")" || rm -f "$link"
        else
            rm -f "$link"
        fi
    done
    rm -f "$UNIT" "$SYSUSERS" "$MODULES" "$CONF_DIR/lunad.toml.example"
    if [ -d "$ROOT$PREFIX" ]; then
        if [ -f "$MARKER" ]; then
            # Only what install put there: an older install wrote its marker into a
            # PREFIX it shared with other files.
            rm -rf "$VENV"
            rm -f "$SHARE/99-tfluna.rules" "$SHARE/raspberry-pi.md" "$SHARE/security.md" "$MARKER"
            rmdir "$SHARE" 2>/dev/null || true
            rmdir "$ROOT$PREFIX" 2>/dev/null ||
                say "kept $PREFIX: it holds files lunad did not put there"
        else
            say "not removing $PREFIX: it has no .lunad-install marker, so it is not ours"
        fi
    fi
    if [ "${PURGE:-0}" = 1 ]; then
        rm -rf "$CONF_DIR"
    elif [ -d "$CONF_DIR" ]; then
        # Keys are kept like configs; the directories go if install's are empty.
        rmdir "$CONF_DIR/curve/clients" "$CONF_DIR/curve" 2>/dev/null || true
        rmdir "$CONF_DIR" 2>/dev/null ||
            say "kept your configs in /etc/lunad (PURGE=1 removes them)"
    fi
    if live_systemd; then
        systemctl daemon-reload
        systemctl reset-failed 'lunad@*.service' 2>/dev/null || true
    fi
    say "uninstalled (the system user 'lunad' stays)"
}

case $action in
install) do_install ;;
uninstall) do_uninstall ;;
*) die "usage: install.sh install|uninstall" ;;
esac

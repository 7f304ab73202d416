#!/usr/bin/env bash
# Installs what the controller firmware (controller/) needs to build and run, and nothing by
# hand: QEMU's Arm system emulator (Debian's qemu-system-arm) and the source of `core` for the
# nightly toolchain, so that `cargo +nightly build -Zbuild-std=core --target
# thumbv7em-none-eabihf` works without a prebuilt target library.
#
# Idempotent: every step checks first and does nothing when its piece is already there. Exits
# non-zero with a message saying what is missing and what to do when a piece cannot be had.
#
# Why Debian's rust-src: the nightly toolchain on the machines has no `rust-src` component to
# install (rustup's servers are out of reach), but Debian ships the same source as a package.
# It is fetched from the suite named below with a private apt state (the machine's own apt
# configuration is not touched), unpacked with `dpkg -x`, and the nightly toolchain's
# `lib/rustlib/src/rust` is pointed at it.
#
# Versions drift. The verified pair is pinned below: nightly rustc 1.97.0 with Debian's
# rust-src 1.97.x. When the suite moves to another version (or the nightly changes), the script
# says so and stops before any build. Then either
#   - set WHEELLEG_RUST_SRC_SUITE to a suite (or snapshot.debian.org archive, with
#     WHEELLEG_RUST_SRC_ARCHIVE) that carries a matching rust-src, or
#   - install a nightly of the same minor version as the suite's rust-src, or
#   - build inside a Debian chroot of that suite (debootstrap) with its own rustc, cargo and
#     rust-src, which always match each other (RUSTC_BOOTSTRAP=1 allows -Zbuild-std there).
set -euo pipefail

suite="${WHEELLEG_RUST_SRC_SUITE:-forky}"
archive="${WHEELLEG_RUST_SRC_ARCHIVE:-http://deb.debian.org/debian}"
keyring="${WHEELLEG_RUST_SRC_KEYRING:-/usr/share/keyrings/debian-archive-keyring.gpg}"
toolchain="${WHEELLEG_NIGHTLY:-nightly}"
# The rustc minor version the firmware was verified with, and the rust-src versions that go
# with it (Debian revisions of the same minor release).
verified_minor="1.97"
cache="${WHEELLEG_TOOLCHAIN_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/wheelleg-embedded}"

say() { echo "embedded-toolchain: $*" >&2; }
fail() {
    say "error: $*"
    exit 1
}

as_root() {
    if [ "$(id -u)" -eq 0 ]; then
        "$@"
    elif command -v sudo >/dev/null; then
        sudo "$@"
    else
        fail "'$*' needs root (run this script as root or install sudo)"
    fi
}

# --- QEMU -----------------------------------------------------------------------------------
if ! command -v qemu-system-arm >/dev/null; then
    say "installing qemu-system-arm (apt-get)"
    as_root env DEBIAN_FRONTEND=noninteractive apt-get update -qq >/dev/null ||
        fail "apt-get update failed"
    as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
        qemu-system-arm >/dev/null || fail "apt-get install qemu-system-arm failed"
fi
if ! qemu-system-arm -machine help | grep -q '^mps2-an386'; then
    fail "this qemu-system-arm has no mps2-an386 machine (QEMU 4.2 or later has it)"
fi

# --- the nightly toolchain ------------------------------------------------------------------
command -v rustup >/dev/null || fail "rustup not found (install Rust with rustup first)"
if ! rustc "+$toolchain" -V >/dev/null 2>&1; then
    say "installing the $toolchain toolchain"
    rustup toolchain install "$toolchain" --profile minimal >/dev/null ||
        fail "no '$toolchain' toolchain and rustup cannot install one"
fi
rustc_version="$(rustc "+$toolchain" -V)"
rustc_minor="$(echo "$rustc_version" | sed -E 's/^rustc ([0-9]+\.[0-9]+)\..*/\1/')"
sysroot="$(rustc "+$toolchain" --print sysroot)"
host="$(rustc "+$toolchain" -vV | sed -n 's/^host: //p')"
[ -x "$sysroot/lib/rustlib/$host/bin/rust-lld" ] ||
    fail "$toolchain toolchain has no rust-lld (it is part of every rustup rustc since 1.50)"
if [ "$rustc_minor" != "$verified_minor" ]; then
    say "warning: $rustc_version is not the verified $verified_minor; the source of core must match it"
fi

# --- the source of core (rust-src) ----------------------------------------------------------
src_link="$sysroot/lib/rustlib/src/rust"
have_src_version() {
    # The source tree's version file (Debian's package and rustup's component both carry it).
    [ -f "$src_link/library/core/Cargo.toml" ] || return 1
    if [ -f "$src_link/version" ]; then cat "$src_link/version"; else echo unknown; fi
}

if ! have_src_version >/dev/null; then
    command -v apt-get >/dev/null && command -v dpkg >/dev/null ||
        fail "no rust-src for $toolchain and no apt-get/dpkg to fetch Debian's (use rustup component add rust-src where rustup's servers are reachable)"
    [ -f "$keyring" ] || fail "keyring $keyring not found (set WHEELLEG_RUST_SRC_KEYRING)"
    apt_dir="$cache/apt-$suite"
    mkdir -p "$apt_dir/lists/partial" "$apt_dir/sources" "$apt_dir/archives/partial"
    cat >"$apt_dir/sources/rust-src.sources" <<EOF
Types: deb
URIs: $archive
Suites: $suite
Components: main
Signed-By: $keyring
EOF
    apt_opts=(
        -o "Dir::Etc::SourceList=/dev/null"
        -o "Dir::Etc::SourceParts=$apt_dir/sources"
        -o "Dir::State::Lists=$apt_dir/lists"
        -o "Dir::Cache::Archives=$apt_dir/archives"
        -o "Dir::State::Status=/var/lib/dpkg/status"
        -o "APT::Sandbox::User=root"
    )
    say "reading the package list of Debian $suite (private apt state in $apt_dir)"
    apt-get "${apt_opts[@]}" -qq update >/dev/null 2>"$apt_dir/update.log" || {
        cat "$apt_dir/update.log" >&2
        fail "apt-get update of suite $suite failed"
    }
    src_version="$(apt-cache "${apt_opts[@]}" show rust-src 2>/dev/null |
        sed -n 's/^Version: //p' | head -1)"
    [ -n "$src_version" ] || fail "suite $suite has no rust-src package"
    # Debian versions look like 1.97.1+dfsg1-1: the upstream minor is what must match.
    src_minor="$(echo "$src_version" | sed -E 's/^([0-9]+:)?([0-9]+\.[0-9]+)\..*/\2/')"
    if [ "$src_minor" != "$rustc_minor" ]; then
        fail "Debian $suite has rust-src $src_version but the toolchain is $rustc_version: core's source must match the compiler. Set WHEELLEG_RUST_SRC_SUITE (or WHEELLEG_RUST_SRC_ARCHIVE, e.g. a snapshot.debian.org date) to one carrying rust-src $rustc_minor.x, install a $src_minor nightly, or build in a Debian $suite chroot with its own rustc, cargo and rust-src"
    fi
    unpack="$cache/rust-src-$src_version"
    if [ ! -f "$unpack/usr/lib/rustlib/src/rust/library/core/Cargo.toml" ]; then
        say "downloading rust-src $src_version"
        rm -rf "$unpack.partial"
        mkdir -p "$unpack.partial"
        (cd "$unpack.partial" && apt-get "${apt_opts[@]}" -qq download "rust-src=$src_version" >/dev/null) ||
            fail "apt-get download rust-src=$src_version failed"
        dpkg -x "$unpack.partial"/rust-src_*.deb "$unpack.partial/root"
        rm -rf "$unpack"
        mv "$unpack.partial/root" "$unpack"
        rm -rf "$unpack.partial"
        echo "$src_version" >"$unpack/usr/lib/rustlib/src/rust/version"
    fi
    root_src="$unpack/usr/lib/rustlib/src/rust"
    [ -f "$root_src/library/core/Cargo.toml" ] ||
        fail "rust-src $src_version has no library/core (package layout changed)"
    mkdir -p "$(dirname "$src_link")"
    rm -rf "$src_link"
    ln -s "$root_src" "$src_link"
    say "pointed $toolchain's lib/rustlib/src/rust at rust-src $src_version"
fi

src_version="$(have_src_version)"
src_minor="$(echo "$src_version" | sed -E 's/^([0-9]+:)?([0-9]+\.[0-9]+)\..*/\2/')"
if [ "$src_version" != unknown ] && [ "$src_minor" != "$rustc_minor" ]; then
    fail "the source of core ($src_version) does not match $rustc_version: remove $src_link and run this script again with WHEELLEG_RUST_SRC_SUITE naming a suite with rust-src $rustc_minor.x"
fi
# Cargo's -Zbuild-std also needs the library workspace's lockfile.
[ -f "$src_link/library/Cargo.lock" ] || fail "$src_link/library/Cargo.lock missing (incomplete rust-src)"

say "ready: $rustc_version, core source $src_version, $(qemu-system-arm --version | head -1)"

# Shared by run-vivid, run-vimc and run-keys: boots Debian's own kernel (downloaded and unpacked,
# not installed) in qemu with TCG, from an initramfs holding busybox, the test's kernel modules
# with their dependencies, and a test harness (tests/kernel/<suite>.rs) with its shared libraries.
#
# The runner sets `suite` (vivid, vimc, keys: the marker prefix and the harness's name) and
# calls, in order: `kernel` (the kernel package, cached in target/kernel/<version>/),
# `add_module NAME` for each module the guest loads (resolved with its dependencies through
# modules.dep, or an out-of-tree .ko path) with `module_params NAME "..."` where needed,
# `build_harness`, then `boot "<shell lines run in the guest after the modules are loaded>"`
# (before it, `add_binary` puts another host program into the guest, and the runner may copy
# files under "$ird"), which exits 0 only when the guest printed `<SUITE>-RESULT: PASS` as often
# as `expect_passes` says (default 1) and every `<SUITE>-EXIT ...: N` line has N = 0.
# Environment: KERNEL_TEST_TIMEOUT (seconds, default 300), KERNEL_TEST_KEEP=1 keeps the work
# directory. Needs: qemu-system-x86 busybox-static kmod (depmod), apt, the Rust toolchain.
set -euo pipefail
cd "$(dirname "$0")/../.."
root=$PWD
target=${CARGO_TARGET_DIR:-$root/target}
timeout_s=${KERNEL_TEST_TIMEOUT:-300}
expect_passes=1
SUITE=$(tr '[:lower:]' '[:upper:]' <<<"$suite")

say() { printf 'run-%s [%ss]: %s\n' "$suite" "$SECONDS" "$*" >&2; }
die() { say "error: $*"; exit 1; }

for tool in qemu-system-x86_64 busybox depmod apt-cache apt-get dpkg cargo gzip ldd; do
    command -v "$tool" >/dev/null 2>&1 || [ -x "/sbin/$tool" ] || [ -x "/usr/sbin/$tool" ] ||
        die "$tool not found (apt-get install qemu-system-x86 busybox-static kmod)"
done
depmod=$(command -v depmod || echo /sbin/depmod)
# busybox must be static: it runs in the guest without any library.
busybox=/bin/busybox
[ -x "$busybox" ] || busybox=$(command -v busybox)
if ldd "$busybox" >/dev/null 2>&1; then
    die "$busybox is dynamically linked: install busybox-static"
fi

work=$(mktemp -d "${TMPDIR:-/tmp}/run-$suite.XXXXXX")
[ -n "${KERNEL_TEST_KEEP:-}" ] && say "work directory $work" || trap 'rm -rf "$work"' EXIT
ird=$work/initramfs
mkdir -p "$ird"/{bin,dev,proc,sys,tmp,modules}

# The kernel: the package linux-image-amd64 depends on, e.g. linux-image-6.1.0-NN-amd64.
kernel() {
    pkg=$(apt-cache depends linux-image-amd64 2>/dev/null |
        awk '/Depends: linux-image-[0-9]/ {print $2; exit}')
    [ -n "$pkg" ] || die "apt-cache depends linux-image-amd64 names no kernel package (apt-get update?)"
    kver=${pkg#linux-image-}
    cache=$target/kernel/$kver
    if [ ! -f "$cache/.unpacked" ]; then
        say "downloading $pkg"
        rm -rf "$cache" && mkdir -p "$cache/deb"
        # apt drops privileges to _apt for downloads, which needs a directory it can write.
        chmod 777 "$cache/deb"
        (cd "$cache/deb" && apt-get download -q "$pkg") || die "apt-get download $pkg failed"
        dpkg -x "$cache"/deb/*.deb "$cache/root"
        rm -rf "$cache/deb"
        "$depmod" -b "$cache/root" "$kver"
        touch "$cache/.unpacked"
    else
        say "kernel $kver from $cache"
    fi
    kroot=$cache/root
    vmlinuz=$kroot/boot/vmlinuz-$kver
    moddir=$kroot/lib/modules/$kver
    [ -f "$vmlinuz" ] || die "$vmlinuz missing"
    declare -gA deps=() seen=() params=()
    while IFS= read -r line; do
        deps[${line%%:*}]=${line#*:}
    done < "$moddir/modules.dep"
    insmods=""
}

# Copies one module (decompressed) into the initramfs, once, after its dependencies.
copy_module() {
    local m=$1 d name
    [ -n "${seen[$m]:-}" ] && return
    seen[$m]=1
    for d in ${deps[$m]:-}; do copy_module "$d"; done
    name=$(basename "$m")
    local src=$m
    [ "${m#/}" = "$m" ] && src=$moddir/$m
    case $name in
        *.ko) cp "$src" "$ird/modules/$name" ;;
        *.ko.xz) xz -dc "$src" > "$ird/modules/${name%.xz}"; name=${name%.xz} ;;
        *.ko.zst) zstd -qdc "$src" > "$ird/modules/${name%.zst}"; name=${name%.zst} ;;
        *.ko.gz) gzip -dc "$src" > "$ird/modules/${name%.gz}"; name=${name%.gz} ;;
        *) die "unknown module file $m" ;;
    esac
    insmods+="$name "
}

# A module of the kernel by name (vivid), or an out-of-tree .ko by absolute path, whose
# dependencies (modinfo's `depends`) are the kernel's.
add_module() {
    local want=$1 m d
    if [ "${want#/}" != "$want" ]; then
        for d in $("$(command -v modinfo || echo /sbin/modinfo)" -F depends "$want" | tr ',' ' '); do
            m=$(printf '%s\n' "${!deps[@]}" | grep -E "/$d\.ko(\.[a-z]+)?$" | head -1)
            [ -n "$m" ] || die "$want needs $d, which $moddir does not have"
            copy_module "$m"
        done
        copy_module "$want"
        return
    fi
    m=$(printf '%s\n' "${!deps[@]}" | grep -E "/$want\.ko(\.[a-z]+)?$" | head -1)
    [ -n "$m" ] || die "no $want module in $moddir/modules.dep"
    copy_module "$m"
}

module_params() { params[$1.ko]=$2; }

# The harnesses are example targets of the main package (see Cargo.toml), built as `cargo test`
# builds them.
build_harness() {
    say "building tests/kernel/$suite.rs"
    cargo build --quiet --example "$suite"
    bin=$target/debug/examples/$suite
    [ -x "$bin" ] || die "$bin was not built"
}

# A host program at guest path DEST, without its debug info (smaller initramfs, faster to pack
# and boot), and every shared library it loads, at the path the loader looks for it.
add_binary() { # SRC DEST
    local src=$1 dest=$2 lib
    mkdir -p "$ird$(dirname "$dest")"
    if command -v objcopy >/dev/null; then
        objcopy --strip-debug "$src" "$ird$dest"
    else
        cp "$src" "$ird$dest"
    fi
    for lib in $(ldd "$src" | grep -oE '/[^ ]+'); do
        mkdir -p "$ird$(dirname "$lib")"
        cp -L "$lib" "$ird$lib"
    done
}

boot() {
    local body=$1
    cp "$busybox" "$ird/bin/busybox"
    ln -s busybox "$ird/bin/sh"
    add_binary "$bin" "/$suite"
    local loads="" m
    for m in $insmods; do
        loads+="insmod /modules/$m ${params[$m]:-} || echo \"$SUITE-GUEST: insmod $m failed\""$'\n'
    done
    cat > "$ird/init" <<INIT
#!/bin/sh
export PATH=/bin LD_LIBRARY_PATH=/lib/x86_64-linux-gnu:/usr/lib/x86_64-linux-gnu
/bin/busybox --install -s /bin
mount -t proc proc /proc
mount -t sysfs sysfs /sys
mount -t devtmpfs devtmpfs /dev
mount -t tmpfs tmpfs /tmp
echo "$SUITE-GUEST: kernel \$(uname -r)"
$loads
$body
poweroff -f
INIT
    chmod 755 "$ird/init"
    (cd "$ird" && find . | "$busybox" cpio -o -H newc 2>/dev/null | gzip -1 > "$work/initrd.gz")

    # KVM is not used: nested virtualisation hangs on CI machines; TCG boots in seconds.
    say "booting $kver under qemu (TCG, timeout ${timeout_s}s)"
    local log=$work/serial.log start=$SECONDS qemu_rc
    set +e
    timeout "$timeout_s" qemu-system-x86_64 -accel tcg -m 512 -nographic -no-reboot \
        -kernel "$vmlinuz" -initrd "$work/initrd.gz" \
        -append "console=ttyS0 quiet panic=-1" </dev/null > "$log" 2>&1
    qemu_rc=$?
    set -e
    tr -d '\r' < "$log"
    say "guest ran $((SECONDS - start))s (qemu exit $qemu_rc)"
    [ "$qemu_rc" -ne 124 ] || die "timed out after ${timeout_s}s"
    local out
    out=$(tr -d '\r' < "$log")
    if [ "$(grep -c "^$SUITE-RESULT: PASS" <<<"$out")" -eq "$expect_passes" ] &&
       grep -q "^$SUITE-EXIT" <<<"$out" &&
       ! grep "^$SUITE-EXIT" <<<"$out" | grep -vq ': 0$'; then
        say "PASS"
        exit 0
    fi
    die "the $suite checks did not pass (see the guest output above)"
}

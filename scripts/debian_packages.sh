# Sourced by the setup scripts: install_debian PACKAGE... installs the Debian packages given
# (none: nothing) with apt-get, through sudo unless run as root.
install_debian() {
    (($#)) || return 0
    local sudo=""
    [[ $(id -u) -eq 0 ]] || sudo="sudo"
    echo "installing Debian packages: $*"
    $sudo apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq "$@" >/dev/null
}

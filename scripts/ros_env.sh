# Environment every project command runs with (sourced, not executed).
# DDS traffic must never leave this machine.
# EKF_VENV selects another venv than .venv (scripts/test_ubuntu2404.sh: .venv-2404).
_EKF_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
export VIRTUAL_ENV="${EKF_VENV:-$_EKF_ROOT/.venv}"
export PATH="$VIRTUAL_ENV/bin:$PATH"
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
export RMW_IMPLEMENTATION="${RMW_IMPLEMENTATION:-rmw_fastrtps_cpp}"
export AMENT_PREFIX_PATH="$VIRTUAL_ENV${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
export MPLBACKEND=Agg
export PYTHONUNBUFFERED=1

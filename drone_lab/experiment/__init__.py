"""The lossy-link experiment: network namespaces, packet loss, sweeps and figures."""

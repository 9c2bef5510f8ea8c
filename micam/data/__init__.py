"""Files micam installs on a machine: udev rules (udev/) and systemd units (systemd/)."""

"""mocap: FORMAT v1 readers and writers (markers, robot logs, campaign manifests); units converted once, at the file boundary."""

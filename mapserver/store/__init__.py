"""What the map server keeps on disk: the scan journal and its snapshots, ROS map files,
scan files, atomic writes, the data dir's lock, and the offline map build."""

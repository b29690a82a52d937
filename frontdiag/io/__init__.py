"""Reading and writing recordings: ROS 1 bags, ROS 2 bags (sqlite3 / MCAP), plain MCAP."""

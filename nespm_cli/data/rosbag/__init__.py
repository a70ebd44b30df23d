"""``nespm import``: ROS 1 / ROS 2 bags -> A-KIT track folders (docs/rosbags.md), one concept a module:

* :mod:`~nespm_cli.data.rosbag.spec`: the import spec (TOML topics -> channels, frames, origin), read and checked;
* :mod:`~nespm_cli.data.rosbag.messages`: opening a bag, pulling fields of topics into arrays, the ROS -> bench
  frame and unit conversions;
* :mod:`~nespm_cli.data.rosbag.inspect_bag`: what a bag says about itself (``--list``, frame_ids, first fix);
* :mod:`~nespm_cli.data.rosbag.importer`: :func:`~nespm_cli.data.rosbag.importer.import_bag`, a bag -> a
  checked ``OUT/TrajectoryN``.

Importing the package imports none of them (nor ``rosbags``): the command imports the module it needs.
"""

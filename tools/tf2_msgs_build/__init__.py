"""The parts of ``tools/build_tf2_msgs.py``, which builds ROS 2's ``tf2_msgs`` into this environment.

The script itself only parses its command line and maps outcomes to exit codes; the work is here,
one job per module:

* ``common``: the install layout (prefix, site-packages), progress logging, the build error;
* ``definitions``: what tf2_msgs is: its ``.msg`` texts, the packages they use, the type supports;
* ``prerequisites``: finding gcc/g++, ``Python.h``, numpy and the rosidl generator wheels;
* ``generate``: running the rosidl generators on the definitions;
* ``compile``: compiling the generated C/C++ sources into the libraries and extension modules;
* ``stage``: laying out the Python package, headers, definitions and ament index markers;
* ``install``: copying the staged tree into the environment (with a dist-info), and uninstalling;
* ``build``: the whole build in a temporary folder, prerequisites to install;
* ``cdr``: the self-test's sample message, DDS type name and CDR byte comparisons (rosbags);
* ``selftest``: the publisher and subscriber processes of the round trip;
* ``verify``: whether tf2_msgs imports, and running the round trip.

``tools/`` is not a package: the script puts its own folder on ``sys.path`` and imports
``tf2_msgs_build`` from there (tests/ros2/test_tf2_msgs_build.py does the same).
"""

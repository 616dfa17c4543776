"""A scanning session as a rosbag2: writing it, reading it back, and the views in it.

Nothing here imports ROS: the pure-Python ``rosbags`` package writes and reads
the bag (rosbag2 metadata, MCAP or sqlite3 storage) and (de)serializes CDR; the
message fields are decoded by :mod:`sfs_ros.cell_logic.message_fields`, as the nodes do.

* :mod:`.layout`: the topics, their types and QoS, the recorder's own records
  (``sfs/parameters``, ``sfs/scan``), where bags go;
* :mod:`.writing`: :class:`BagWriter`, every message on disk before the next;
* :mod:`.reading`: :func:`open_bag`, the messages of a bag folder or file;
* :mod:`.salvage`: the whole messages of an MCAP file that was cut or not closed;
* :mod:`.views`: :func:`read_bag`, the views as the carving node received them.
"""

from .layout import (
                     BAG_SUFFIXES,
                     CAPTURE,
                     DEFAULT,
                     PARAMETERS_TOPIC,
                     RECORDER_TOPICS,
                     RESULT,
                     SCAN_TOPIC,
                     STORAGES,
                     TOPICS,
                     bag_folder,
                     new_bag_folder,
                     parameters_message,
                     scan_message,
)
from .reading import Bag, BagMessage, open_bag
from .views import BagViewSet, read_bag
from .writing import BagWriter

__all__ = ["CAPTURE", "RESULT", "DEFAULT", "TOPICS", "PARAMETERS_TOPIC", "SCAN_TOPIC",
           "RECORDER_TOPICS", "STORAGES", "BAG_SUFFIXES", "bag_folder", "new_bag_folder",
           "parameters_message",
           "scan_message", "BagWriter", "BagMessage", "Bag", "open_bag", "BagViewSet",
           "read_bag"]

"""rosbag2-compatible MCAP bags: layout, writer, reader, recovery, decoding (no rclpy).

Layout (what ``ros2 bag record -s mcap`` writes in Jazzy)::

    bags/NAME/
        metadata.yaml      rosbag2 metadata version 9, storage_identifier mcap
        NAME_0.mcap        profile ros2; schemas ros2msg (full .msg text); channels cdr

MCAP details (rosbag2_storage_mcap conventions):

* one Schema per message type: name ``pkg/msg/Type``, encoding ``ros2msg``, data = the full
  definition text (:func:`magtune_core.bags.msgdefs.full_definition`);
* one Channel per topic: message encoding ``cdr``, metadata ``offered_qos_profiles`` (the YAML
  sequence of QoS maps rosbag2 serializes with its version-9 string enums) and
  ``topic_type_hash`` (RIHS01);
* Message ``log_time`` = receive time, ``publish_time`` = the recorder's send time (for our
  recorder both are the receive time on the node's clock, i.e. sim time with use_sim_time);
* chunked, zstd-compressed chunks, message indexes, summary with statistics, chunk indexes
  and a ``rosbag2`` Metadata record holding ``serialized_metadata`` (as rosbag2 does on close).

Crash safety: every chunk is written to the OS as soon as it is complete (the output stream is
unbuffered), and :meth:`BagWriter.flush` closes the open chunk on demand (the recorder calls it
periodically). After a SIGKILL the file holds every completed chunk but no summary; read it
with :func:`magtune_core.bags.scan.scan` (or any MCAP stream reader) and rewrite the summary
and ``metadata.yaml`` with :func:`magtune_core.bags.recover.recover`. What is lost: messages of
the chunk still open in memory (at most ``chunk_size`` bytes or ``flush`` period of data).

Modules: ``layout`` (metadata.yaml, QoS, records), ``writer`` (BagWriter), ``reader``
(iter_messages, topics_of, info), ``scan`` (sequential scan of damaged files), ``recover``,
``decode`` (CDR via rosbags), ``msgdefs`` (ros2msg definitions and type hashes). The common
API is re-exported here: ``from magtune_core import bags; bags.iter_messages(...)``.
"""
from .layout import (
                     BagMessage,
                     TopicInfo,
                     build_metadata,
                     has_summary,
                     mcap_file_name,
                     qos_dict,
                     qos_yaml,
                     read_metadata,
                     resolve_mcap,
                     resolve_mcaps,
                     write_metadata,
)
from .reader import info, iter_messages, ties_in_topic_order, topics_of
from .writer import DEFAULT_CHUNK_SIZE, BagWriter

__all__ = ["DEFAULT_CHUNK_SIZE", "BagMessage", "BagWriter", "TopicInfo", "build_metadata", "has_summary", "info",
           "iter_messages", "mcap_file_name", "qos_dict", "qos_yaml", "read_metadata", "resolve_mcap", "resolve_mcaps", "ties_in_topic_order",
           "topics_of",
           "write_metadata"]

"""The suite's topics in a rosbag2 (raw images, pair_info, camera_info), with ``rosbags`` alone."""

import pathlib

SIDES = ('left', 'right')


def image_pair_prefixes(topics):
    """
    Return the prefixes P of ``topics`` holding both P + left/image_raw and P + right/image_raw.

    ``/stereo/`` for the suite's own topics, ``/`` for the root namespace, ``/cam_`` for
    ``/cam_left/image_raw`` and ``/cam_right/image_raw`` (any topic ending in left/image_raw
    was read as a camera before namespaces were told apart).
    """
    found = [{topic[:-len(f'{side}/image_raw')] for topic in topics
              if topic.endswith(f'{side}/image_raw')} for side in SIDES]
    return sorted(found[0] & found[1])


def pair_namespace(path, topics, namespace=''):
    """
    Return the prefix of the image pair to read from a bag with ``topics`` (see above).

    The pair's topics are the prefix + ``left/image_raw``, ``right/image_raw``,
    ``left/camera_info``, ``right/camera_info`` and ``pair_info``. ``namespace`` (the driver's
    ``bag_namespace``): '' takes the bag's one prefix; a bag of several rigs (``/rig1/
    stereo/``, ``/rig2/stereo/``) then raises a ValueError naming them (their frames were
    merged before), unless one of them is a namespace's own pair (``/stereo/`` is taken over
    ``/stereo/ir_``); ``/rig2/stereo`` (slashes optional) chooses one, ``/`` the root
    namespace, and a prefix as listed (``/cam_``) itself. A ValueError names what the bag has
    when nothing matches.
    """
    prefixes = image_pair_prefixes(topics)
    if namespace:
        stripped = namespace.strip('/')
        for wanted in (namespace, f'/{stripped}/' if stripped else '/'):
            if wanted in prefixes:
                return wanted
        raise ValueError(f'{path}: no image pair under {namespace!r} (bag_namespace); image '
                         f'pairs under: {", ".join(prefixes) or "none"}; topics: '
                         f'{sorted(topics)}')
    if len(prefixes) == 1:
        return prefixes[0]
    # /stereo/left and /stereo/ir_left: the namespace's own pair, as before prefixes (the
    # other by bag_namespace /stereo/ir_).
    namespaces = [prefix for prefix in prefixes if prefix.endswith('/')]
    if len(namespaces) == 1:
        return namespaces[0]
    if not prefixes:
        raise ValueError(f'{path}: expected topics ending in left/image_raw and '
                         f'right/image_raw, found {sorted(topics)}')
    raise ValueError(f'{path}: image pairs under {len(prefixes)} namespaces '
                     f'({", ".join(prefixes)}): choose one (bag_namespace; '
                     f'--bag-namespace of calibrate and rig-pose)')


def raw_image_messages(path, zero_stamped=None, namespace='', notes=None):
    """
    Yield ``(side, stamp_ns, msg)`` of a bag's left/image_raw and right/image_raw topics.

    ``msg`` is a rosbags sensor_msgs/Image (fields as in ROS); messages come in bag order. The
    topics are those of one namespace (``pair_namespace``). A missing bag or a bag without
    both topics raises a ValueError naming what was found.
    ``stamp_ns`` is the image's header stamp; an image stamped 0 (a camera node that never set
    it) gets the time the recorder received it instead, and is counted in ``zero_stamped``
    (``{side: count}``) when given: without it every frame had the same time, and the two
    cameras' frames could not be paired. ``notes`` (a list), when given, gets what reading
    the bag worked around (``open_bag``'s notes).
    """
    from rosbags.typesys import get_typestore, Stores

    from st_stereo.bag_reading import bag_messages, normalized_msgtype, open_bag
    path = pathlib.Path(path)
    typestore = get_typestore(Stores.ROS2_JAZZY)
    reader = open_bag(path)
    if notes is not None:
        notes.extend(reader.notes)
    try:
        chosen = pair_namespace(path, reader.topics, namespace)
        wanted = {c.id: side for c in reader.connections for side in SIDES
                  if c.topic == f'{chosen}{side}/image_raw'}
        for connection, received, data in bag_messages(
                reader, [c for c in reader.connections if c.id in wanted]):
            # Older bags name types without the /msg/ part (sensor_msgs/Image).
            msg = typestore.deserialize_cdr(data, normalized_msgtype(connection.msgtype))
            stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            side = wanted[connection.id]
            if stamp == 0:
                stamp = received
                if zero_stamped is not None:
                    zero_stamped[side] = zero_stamped.get(side, 0) + 1
            yield side, stamp, msg
    finally:
        reader.close()


def recorded_pair_info(path, namespace='', notes=None):
    """
    Return ``{stamp_ns: {key: value}}`` of a bag's ``pair_info`` topic (empty without one).

    The driver's ``pair_info`` (diagnostic_msgs/DiagnosticArray stamped with each pair's stamp)
    carries both cameras' acquisition stamps and the pair's skew: a bag whose images share the
    pair's stamp keeps the skew only there. Topics ending in ``pair_info`` of another type are
    ignored, and so are those of another namespace than the image pair's (``pair_namespace``).
    ``notes`` (a list), when given, gets what reading the bag worked around.
    """
    from rosbags.typesys import get_typestore, Stores

    from st_stereo.bag_reading import bag_messages, normalized_msgtype, open_bag
    path = pathlib.Path(path)
    typestore = get_typestore(Stores.ROS2_JAZZY)
    reader = open_bag(path)
    if notes is not None:
        notes.extend(reader.notes)
    out = {}
    try:
        chosen = pair_namespace(path, reader.topics, namespace)
        connections = [c for c in reader.connections if c.topic == f'{chosen}pair_info' and
                       normalized_msgtype(c.msgtype) == 'diagnostic_msgs/msg/DiagnosticArray']
        if not connections:
            return out
        for connection, _, data in bag_messages(reader, connections):
            msg = typestore.deserialize_cdr(data, normalized_msgtype(connection.msgtype))
            stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            out[stamp] = {item.key: item.value for status in msg.status
                          for item in status.values}
    finally:
        reader.close()
    return out


def recorded_calibrations(path, namespace=''):
    """
    Return the left and right CameraCalibration of a bag's first camera_info messages.

    The ``left/camera_info`` and ``right/camera_info`` beside the image pair
    (``pair_namespace``); a ValueError names what the bag has when one is missing (a bag of
    image_raw alone has no calibration).
    """
    from rosbags.typesys import get_typestore, Stores

    from st_stereo.bag_reading import bag_messages, normalized_msgtype, open_bag
    from st_stereo.core.calibration.files import calibration_from_camera_info
    path = pathlib.Path(path)
    typestore = get_typestore(Stores.ROS2_JAZZY)
    reader = open_bag(path)
    found = {}
    topics = sorted(reader.topics)
    try:
        chosen = pair_namespace(path, topics, namespace)
        wanted = {c.id: side for c in reader.connections for side in SIDES
                  if c.topic == f'{chosen}{side}/camera_info' and
                  normalized_msgtype(c.msgtype) == 'sensor_msgs/msg/CameraInfo'}
        for connection, _, data in bag_messages(
                reader, [c for c in reader.connections if c.id in wanted]):
            side = wanted[connection.id]
            if side not in found:
                found[side] = calibration_from_camera_info(
                    typestore.deserialize_cdr(data, 'sensor_msgs/msg/CameraInfo'), side)
            if len(found) == 2:
                break
    finally:
        reader.close()
    missing = [side for side in SIDES if side not in found]
    if missing:
        raise ValueError(f'{path}: no {" or ".join(missing)}/camera_info message (topics: '
                         f'{topics})')
    return found['left'], found['right']


def bag_pair_namespace(path, namespace=''):
    """Return the topic prefix of a bag's image pair (``pair_namespace``)."""
    from st_stereo.bag_reading import open_bag
    reader = open_bag(pathlib.Path(path))
    try:
        return pair_namespace(path, reader.topics, namespace)
    finally:
        reader.close()

"""Object classes, their ids in instance images (KITTI MOTS convention) and KITTI label names."""

CLASS_IDS = {"car": 1, "pedestrian": 2, "van": 3, "truck": 4, "cyclist": 5}
CLASS_NAMES = {v: k for k, v in CLASS_IDS.items()}
KITTI_TYPES = {"car": "Car", "pedestrian": "Pedestrian", "van": "Van", "truck": "Truck", "cyclist": "Cyclist"}
FROM_KITTI_TYPE = {v: k for k, v in KITTI_TYPES.items()}
DYNAMIC_CLASSES = frozenset(CLASS_IDS)
VEHICLE_CLASSES = frozenset({"car", "van", "truck"})
INSTANCE_IGNORE = 10000
INSTANCE_CLASS_FACTOR = 1000


def instance_class_id(instance_ids):
    """Class id of MOTS-encoded instance ids (`class_id*1000 + instance_id`); 0 for background/ignore."""
    cls = instance_ids // INSTANCE_CLASS_FACTOR
    return cls * (instance_ids != INSTANCE_IGNORE)

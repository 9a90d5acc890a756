"""Map data: frames, keyframes, map points and the covisibility graph (data only; algorithms live
in tracking/ and mapping/)."""

"""Perception (thesis 000 §3.3.1, §5.2): AprilTags seen by the robot's RGB-D camera.

* :mod:`.camera` — pinhole intrinsics, passed explicitly everywhere;
* :mod:`.detector` — tag36h11 detection, both planar pose hypotheses, their resolution by the
  image, depth or a prior (ViSP 3.5 through ``marionette._visp``);
* :mod:`.objects` — poses of tagged bodies from every visible tag at once;
* :mod:`.synthetic` — exact pinhole renderings with ground truth, for tests and benchmarks;
* :mod:`.node` — ``marionette perceive``: camera frames in, detections and object poses out (LCM);
* :mod:`.pbvs` — position-based visual-servoing references (eq. 5.1-5.3);
* :mod:`.calibration` — hand-eye (Tsai-Lenz) and joint-offset calibration (ch. 4.2);
* :mod:`.arm_calibration` — an arm's encoder offsets from its wrist tags seen by the head camera.
"""

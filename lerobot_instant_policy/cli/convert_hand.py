"""``lerobot-ip-convert-hand``: recordings of a human hand demonstrating (RGB-D + landmarks) → demonstrations in the
data contract, the hand read as the gripper (docs/deployment.md section 8).

    lerobot-ip-convert-hand --recordings demos/hand --out demos/hand-converted --repo-id local/hand
    lerobot-ip-convert-hand --recordings demos/hand --detector-model hand_landmarker.task --detect-only
    lerobot-ip-convert-hand ... --close-below 0.065 --open-above 0.08 --hand Right --max-gap-frames 3

``--recordings``: one recording folder or a folder of them (format: ``perception.hand_recording``), one episode each.
``--detector-model``: run MediaPipe's hand landmarker (the ``hand`` extra) on every recording first and write its
image landmarks into them (``--redetect``: also on recordings that have landmarks); ``--detect-only`` stops there.
A recording that carries ``object_mask`` (a segmenter's task-object pixels) is segmented by it; one without, by the
table plane. The conversion itself is :mod:`lerobot_instant_policy.perception.hand_convert`.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ..perception.hand import HandGapError, HandMappingConfig
from ..perception.hand_convert import HandConversionError, HandConvertSettings, convert_hand_recordings
from ..perception.hand_detector import HandDetectorError, detect_recording_landmarks
from ..perception.hand_recording import METADATA_FILE, HandRecordingError, find_hand_recordings
from ..perception.segmentation import EmptyPointCloudError
from .arguments import xyz


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="lerobot-ip-convert-hand", description=__doc__.split("\n\n")[0])
    parser.add_argument("--recordings", type=Path, required=True, help="a hand recording folder, or a folder of them")
    parser.add_argument("--out", type=Path, help="root of the converted dataset to create")
    parser.add_argument("--repo-id")
    parser.add_argument("--detector-model", type=Path, help="MediaPipe's hand_landmarker.task: detect landmarks first")
    parser.add_argument("--redetect", action="store_true", help="detect again on recordings that have landmarks")
    parser.add_argument("--detect-only", action="store_true", help="stop after writing the detected landmarks")
    parser.add_argument("--min-detection-confidence", type=float, default=0.5)
    defaults = HandMappingConfig()
    parser.add_argument("--close-below", type=float, default=defaults.close_below_m,
                        help="gripper closes when the thumb-index tip distance falls below this (m)")
    parser.add_argument("--open-above", type=float, default=defaults.open_above_m,
                        help="gripper opens again above this (m)")
    parser.add_argument("--gripper-hold-frames", type=int, default=defaults.gripper_hold_frames,
                        help="frames in a row the aperture must call for a gripper change before it changes (1: off)")
    parser.add_argument("--max-gap-frames", type=int, default=defaults.max_gap_frames,
                        help="longest run of frames without a hand that is bridged (longer: an error)")
    parser.add_argument("--ee-offset", type=xyz, default=defaults.ee_offset_m, help="x,y,z (m, EE frame)")
    parser.add_argument("--window-frames", type=int, default=HandConvertSettings.window_frames,
                        help="landmarks averaged over this many frames centred on each (odd; 1: off) before mapping")
    parser.add_argument("--aperture-window-frames", type=int, default=HandConvertSettings.aperture_window_frames,
                        help="the gripper state reads the median aperture of this many frames centred on each (odd)")
    parser.add_argument("--dwell-frames", type=int, default=HandConvertSettings.dwell_frames,
                        help="the hand holds still over this many frames from each gripper change: their poses are "
                        "averaged (1: off; for a demonstrator who pauses while the fingers close and open)")
    parser.add_argument("--position-smoothing", type=float, default=defaults.position_smoothing)
    parser.add_argument("--rotation-smoothing", type=float, default=defaults.rotation_smoothing)
    parser.add_argument("--hand", choices=("Left", "Right"), help="only frames of this hand count (default: either)")
    parser.add_argument("--min-hand-score", type=float, default=0.5, help="frames below this score are missing")
    parser.add_argument("--hand-radius", type=float, default=0.015,
                        help="points within this distance of the hand's skeleton are removed (m)")
    parser.add_argument("--hand-mask-dilate", type=int, default=2,
                        help="pixels a recording's hand_mask is grown by (a detector's mask misses the hand's rim)")
    parser.add_argument("--num-points", type=int, default=2048)
    parser.add_argument("--workspace-low", type=xyz, default=(0.15, -0.5, -0.05), help="x,y,z (m, world)")
    parser.add_argument("--workspace-high", type=xyz, default=(0.85, 0.5, 0.6), help="x,y,z (m, world)")
    parser.add_argument("--overwrite", action="store_true")
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not args.detect_only and not (args.out and args.repo_id):
        parser.error("converting needs --out and --repo-id (or --detect-only with --detector-model)")
    if args.detect_only and not args.detector_model:
        parser.error("--detect-only needs --detector-model")
    try:
        if args.detector_model:
            for folder in find_hand_recordings(args.recordings):
                if args.redetect or _needs_landmarks(folder):
                    detect_recording_landmarks(folder, args.detector_model, overwrite=args.redetect,
                                               min_confidence=args.min_detection_confidence)
                    print(f"detected hand landmarks in {folder}")
            if args.detect_only:
                return 0
        mapping = HandMappingConfig(
            close_below_m=args.close_below, open_above_m=args.open_above, max_gap_frames=args.max_gap_frames,
            ee_offset_m=args.ee_offset, position_smoothing=args.position_smoothing,
            rotation_smoothing=args.rotation_smoothing, gripper_hold_frames=args.gripper_hold_frames,
        )
        summary = convert_hand_recordings(HandConvertSettings(
            recordings=args.recordings, out=args.out, repo_id=args.repo_id, mapping=mapping,
            window_frames=args.window_frames, aperture_window_frames=args.aperture_window_frames,
            dwell_frames=args.dwell_frames, num_points=args.num_points, hand_radius_m=args.hand_radius,
            hand_mask_dilate_px=args.hand_mask_dilate, min_hand_score=args.min_hand_score,
            hand=args.hand, workspace_low=args.workspace_low, workspace_high=args.workspace_high,
            overwrite=args.overwrite,
        ))
    except (HandConversionError, HandRecordingError, HandGapError, HandDetectorError, EmptyPointCloudError,
            FileExistsError, ValueError) as error:
        print(f"lerobot-ip-convert-hand: error: {error}", file=sys.stderr)
        return 2
    bridged = sum(len(frames) for frames in summary["bridged_frames"])
    print(f"converted {summary['episodes']} hand demonstrations ({summary['frames']} frames, {bridged} bridged) to "
          f"{summary['root']}")
    return 0


def _needs_landmarks(folder: Path) -> bool:
    """Whether the recording in ``folder`` has no landmarks yet (read from its metadata only)."""
    return json.loads((folder / METADATA_FILE).read_text()).get("landmarks") == "none"


if __name__ == "__main__":
    sys.exit(main())

"""See an episode: Rerun recordings of run MCAPs, saved as ``.rrd`` or served locally.

``pip install 'skyvln-eval[viewer]'``; nothing here imports Rerun until a recording is
built or served.
"""

from skyvln_eval.viewer.logs import EpisodeLogRef, RunLogStream, find_episode_logs
from skyvln_eval.viewer.recording import RecordingSummary, recording_id, write_recording

__all__ = [
    "EpisodeLogRef",
    "RecordingSummary",
    "RunLogStream",
    "find_episode_logs",
    "recording_id",
    "write_recording",
]

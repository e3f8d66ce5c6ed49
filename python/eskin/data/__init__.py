"""The data layer: the campaign file format, importers of recorded data, the simulated
campaign and the firmware simulator's replay files. It imports no other eskin layer.
"""

from .campaign import (
    Campaign,
    CampaignFormatError,
    CampaignSignals,
    CampaignWriter,
    EncodedRecording,
    Recovery,
    encode_recording,
    load_campaign,
    recover_campaign,
    save_campaign,
    write_campaign,
)
from .importers import (
    import_csv_folder,
    import_tdms,
    parse_direction,
)
from .replay import (
    REPLAY_MAGIC,
    REPLAY_VERSION,
    ReplayFile,
    ReplayFormatError,
    read_replay_file,
    write_raw_records,
    write_recordings_npy,
    write_replay_arrays,
    write_replay_file,
)
from .skin import Patch, Skin, SkinFormatError, load_skin
from .skin_simulator import SimulatedSkin, simulate_skin
from .simulator import (
    ParticipantStyle,
    RecordingTruth,
    SimulatorConfig,
    iter_recordings,
    simulate,
)

__all__ = [
    "REPLAY_MAGIC",
    "REPLAY_VERSION",
    "Campaign",
    "CampaignFormatError",
    "CampaignSignals",
    "CampaignWriter",
    "EncodedRecording",
    "ParticipantStyle",
    "Patch",
    "RecordingTruth",
    "Recovery",
    "ReplayFile",
    "ReplayFormatError",
    "SimulatedSkin",
    "SimulatorConfig",
    "Skin",
    "SkinFormatError",
    "encode_recording",
    "import_csv_folder",
    "import_tdms",
    "iter_recordings",
    "load_campaign",
    "load_skin",
    "parse_direction",
    "read_replay_file",
    "recover_campaign",
    "save_campaign",
    "simulate",
    "simulate_skin",
    "write_campaign",
    "write_raw_records",
    "write_recordings_npy",
    "write_replay_arrays",
    "write_replay_file",
]

"""The parameters as part of an output's identity, and the settings added since outputs recorded one.

Every sosmatch output records the identity of its inputs and settings (`database.output_markers.fingerprint` of
dicts of `Params` sections); a re-run of the same identity resumes, another one is refused. A new setting would
change every identity, so an upgrade refused every earlier output (nu36) although the new setting, at the value
registered here, behaves as the earlier version did. Hence:

- `ADDED` lists each setting added after outputs existed: its dotted name, the commit that added it, and its
  neutral value (the one at which the code does what the earlier version did on every input; `NO_NEUTRAL` when
  no value does, e.g. a new refusal that cannot be switched off).
- `params_identity` is the identity dict of a Params or one section: a registered setting at its neutral value is
  left out, so an identity is the same before and after the setting existed, and a new setting at a neutral
  default changes no identity. A setting at another value (a default that changes behaviour, or a value set by
  the user) stays in, as it changes the output.
- `identity_versions` builds an identity object the way today's and each earlier sosmatch built it (outputs made
  before this module recorded every setting, the registered ones too), so a command resumes them all.

When to add an entry: whenever a field is added to a Params section, with the value that reproduces the earlier
behaviour; keep the list in the order of addition (tests/test_identity_registry.py fails for a setting that is
neither here nor among those Params had when this registry was made). The entries are what keep earlier outputs
resumable: never remove one. A removed or renamed setting is not handled (earlier outputs recorded it); that test
fails for it too.
"""

from __future__ import annotations

import dataclasses
import functools
import json
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

NO_NEUTRAL = object()  # no value of the setting behaves as the earlier version did


@dataclass(frozen=True)
class Added:
    """A setting added after outputs existed: `name` (dotted), `since` (the commit adding it), `neutral` (the value
    that reproduces the earlier behaviour, or NO_NEUTRAL), `change` (what it changes, for a refusal's message)."""

    name: str
    since: str
    neutral: Any
    change: str

    def is_neutral(self, value: Any) -> bool:
        return self.neutral is not NO_NEUTRAL and value == self.neutral


# Settings added since 2026-12-05 (git log -p plugin/params), in order of addition. Warning thresholds are neutral at
# their default (an output is the same; only what is said of it is new); a setting that changes results or adds a
# refusal is neutral only at the value that switches it off.
ADDED: tuple[Added, ...] = (
    Added("association.georeference_prior_m", "8177bae", 0.0, "georeferenced maps are searched near their "
          "georeference first"),
    Added("quality.warn_flying_height_m", "316458b", 10_000.0, "a warning"),
    Added("pose_check.max_gps_scale_error", "e87af00", NO_NEUTRAL, "poses are refused when their lengths are not "
          "the GPS's metres"),
    Added("pose_check.warn_gps_offset_m", "e87af00", 50.0, "a warning"),
    Added("pose_check.min_gps_agreement", "e87af00", NO_NEUTRAL, "poses are refused when their lengths are not "
          "the GPS's metres"),
    Added("pose_check.min_pair_share", "51572a4", 1 / 3, "a warning"),
    Added("quality.min_image_contrast_to_noise", "de5092e", 3.0, "a warning"),
    Added("quality.min_image_sharpness", "de5092e", 0.15, "a warning"),
    Added("triangulation.whole_masks_only", "21d9831", False, "landmarks are located from the views that see "
          "their mask whole"),
    Added("segmentation.classical_min_ground_resolution_m", "093ffad", 0.0, "a floor under the segmenter's "
          "working pixel"),
    Added("quality.pass_offset_margin", "20ed52f", NO_NEUTRAL, "maps whose passes disagree in height are refused"),
    # added at 90 and lowered to 70 in dc36258: an output of 90 is another one
    Added("segmentation.contrast_reference", "d5251b0", 0.0, "a low-contrast (hazy) flight is stretched before "
          "segmenting"),
    Added("quality.min_jpeg_quality", "d1c47fd", 75.0, "a warning"),
    Added("changes.min_jpeg_quality", "cd668d0", 75.0, "a warning"),
    Added("quality.max_motion_smear_px", "debb177", 2.0, "a warning"),
    Added("changes.max_motion_smear_px", "af76afa", 2.0, "a warning"),
    Added("pose_check.warn_matches_beyond_gate", "75b6bd8", 0.03, "a warning"),
    # a calibration of confidences, registered at its default like fix48's reweighing of absences (no setting):
    # it acts only on claims not tested for a standing object (images missing), and an earlier `changes` or batch
    # output (made with images nearly always) is resumed as it is; `--overwrite` recomputes its claims. At 1.0
    # (its value before) every identity named it: an upgrade refused every batch and, through the full
    # parameters of a map's identity, every map (rev24)
    Added("changes.untested_object_rate", "e04497c", 0.4, "claims not tested for a standing object (no images) "
          "have their confidence lowered"),
    Added("quality.warn_landmarks_per_keyframe", "39e6c0f", 0.3, "a warning"),
    # registered at its default as untested_object_rate is: at False (its behaviour before) every identity would
    # name it, and through a map's full parameters an upgrade would refuse every map; an earlier `changes` output
    # is resumed as it is, `--overwrite` recomputes its verdicts
    Added("changes.object_height_mean", "41ab82a", True, "landmarks whose footprint stands by its mean sweep are "
          "no longer flat"),
    # neutral at False although its default is True since fix76: unlike untested_object_rate and
    # object_height_mean (settings of stages after a map, which through a map's full parameters refused maps they
    # do not change), it changes the map itself (which views are linked, where landmarks are). Registered at True,
    # a map made with the flag off would have today's identity and a `map` run today would take it as done: a
    # flag-off map silently given out as a flag-on one (and so a batch's). At False, as whole_masks_only and
    # contrast_reference (behaviour-changing defaults of the mapping stages), such a map is refused with the note
    # "--set tracking.truncation_aware=false would accept it", which resumes it as it was made
    Added("tracking.truncation_aware", "13d672e", False, "masks cut by the image border are tracked as truncated "
          "views"),
    # registered at its default as untested_object_rate is, not at False as truncation_aware: the check changes no
    # map, it only adds a warning or a refusal. At False every identity would name it, and through a map's full
    # parameters an upgrade would refuse every map and batch made before it (a map made then and resumed is
    # named by `database.code_version`'s notice of other code, which is what says it was never checked)
    Added("quality.lens_check", "9eab6db", True, "maps whose camera lens the images contradict are refused"),
    Added("quality.lens_shift_margin", "9eab6db", 5.0, "the lens check's significance"),
    Added("quality.max_lens_height_shift", "9eab6db", 0.10, "the lens check's refusal"),
    Added("quality.warn_lens_height_shift", "9eab6db", 0.06, "a warning"),
    # module constants of plugin.pose_check.verdict until fix155, at these values: at them the check behaves as
    # before the settings existed (the refusal of exchanged cameras that came with them has no setting)
    Added("pose_check.camera_median_factor", "fb3c401", 10.0, "the cameras a pose check refuses"),
    Added("pose_check.camera_gate_fraction", "fb3c401", 0.5, "the cameras a pose check refuses"),
)

_BY_NAME = {a.name: a for a in ADDED}


@functools.cache
def _section_prefixes() -> dict[type, str]:
    """Each Params section's class -> its dotted prefix ("association."): made once, as every identity asks it
    for every version (a default Params costs 0.1 ms, and building one per field per version made a batch pair's
    fingerprints 24 ms)."""
    from .tree import Params

    default = Params()
    return {type(v): f.name + "." for f in dataclasses.fields(Params)
            if dataclasses.is_dataclass(v := getattr(default, f.name))}  # (not the seed: no section)


def _section_name(obj: Any) -> str:
    """The dotted prefix of a Params (``""``) or of one of its sections (``"association."``)."""
    from .tree import Params

    if isinstance(obj, Params):
        return ""
    prefix = _section_prefixes().get(type(obj))
    if prefix is None:
        raise TypeError(f"{type(obj).__name__} is not a Params section")
    return prefix


class _NotThisVersion(Exception):
    """A setting the version did not have is at a non-neutral value: it cannot have made this output."""


def _identity_dict(params: Any, keep: frozenset[str], absent: frozenset[str], met: dict[str, Added],
                   strict: bool = True) -> dict[str, Any]:
    """The identity dict: registered settings in `keep` always in, in `absent` never (and then they must be
    neutral, unless not `strict`), the others in unless neutral. `met` collects the registered settings found at a
    non-neutral value."""
    out = dataclasses.asdict(params)
    prefix = _section_name(params)
    for added in ADDED:
        if not added.name.startswith(prefix):
            continue
        *sections, key = added.name[len(prefix):].split(".")
        node = out
        for s in sections:
            node = node[s]
        value = node[key]
        if not added.is_neutral(value):
            met[added.name] = added
        if added.name in keep:
            continue
        if added.name in absent:
            if strict and not added.is_neutral(value):
                raise _NotThisVersion(added.name)
            del node[key]
        elif added.is_neutral(value):
            del node[key]
    return out


def params_identity(params: Any) -> dict[str, Any]:
    """The identity dict of a Params or one of its sections: `dataclasses.asdict` without the registered settings
    (`ADDED`) at their neutral value, so that outputs made before such a setting existed keep their identity."""
    return _identity_dict(params, frozenset(), frozenset(), {})


@dataclass(frozen=True)
class IdentityVersions:
    """An identity object as today's sosmatch builds it (`today`), as earlier ones built it for the same inputs
    and settings (`earlier`: distinct from `today`), and as earlier versions built it for the same inputs and
    today's settings where some of them behave otherwise than in that version (`otherwise`: each object with the
    note a refusal of that version's output gives, `otherwise_note`)."""

    today: Any
    earlier: list[Any]
    otherwise: list[tuple[Any, str]]


def otherwise_note(changed: list[Added]) -> str:
    """Why an output with the behaviour of before some settings existed (an earlier version's, or one made at their
    neutral values) is another one: those settings, which behave otherwise at their values here, and the `--set`s
    that would give that behaviour again (and so resume the output). Short: an InputError is cut at 400 characters,
    so what changes is said for one setting only."""
    said = (f"{changed[0].name} ({changed[0].since}: {changed[0].change})" if len(changed) == 1 else
            ", ".join(a.name for a in changed))
    stuck = [a.name for a in changed if a.neutral is NO_NEUTRAL]
    how = (f"no value of {', '.join(stuck)} behaves as before" if stuck else
           " ".join(f"--set {a.name}={json.dumps(a.neutral)}" for a in changed) + " would accept it")
    if len(changed) == 1 and not stuck:
        # the value it was made with, which may be today's default (a setting registered at its default, as
        # quality.lens_check: a map refused at true and run again at false read "the earlier behaviour of
        # quality.lens_check ... --set quality.lens_check=true", as if true were not the default; rev40)
        a = changed[0]
        return f"one made with {a.name}={json.dumps(a.neutral)} or before it ({a.since}: {a.change}); {how}"
    return f"one made with the earlier behaviour of {said}; {how}"


def identity_eras() -> list[Callable[[Any], dict[str, Any]]]:
    """How each version turns Params (or a section) into its identity dict: today's (`params_identity`) first,
    then the versions before each registered setting (without it and the later ones, which must then be
    neutral: else the version could not have made the output and the function raises) and the versions between
    the first entries and this module (every setting in, as `dataclasses.asdict` gave them), newest first. A
    chain of identities (a batch's map -> pair -> changes) builds each link with the same era."""
    names = [a.name for a in ADDED]
    eras: list[Callable[[Any], dict[str, Any]]] = [params_identity]
    for k in range(len(names), -1, -1):  # versions with the first k registered settings, recorded at any value
        keep, absent = frozenset(names[:k]), frozenset(names[k:])
        eras.append(lambda p, keep=keep, absent=absent: _identity_dict(p, keep, absent, {}))
    return eras


def build_versions(build: Callable[[Callable[[Any], dict[str, Any]]], Any]) -> list[Any]:
    """`build(as_dict)` for each of `identity_eras` (None where that version cannot have made it)."""
    out = []
    for as_dict in identity_eras():
        try:
            out.append(build(as_dict))
        except _NotThisVersion:
            out.append(None)
    return out


def each_version(make: Callable[..., Any], *parts: list[Any]) -> list[Any]:
    """A chained identity per version: `make(*each version's parts)` over lists in `build_versions` order (the
    chain's earlier links); None where a version cannot have made one of the parts."""
    return [None if any(p is None for p in ps) else make(*ps) for ps in zip(*parts)]


def identity_versions(build: Callable[[Callable[[Any], dict[str, Any]]], Any]) -> IdentityVersions:
    """`build(as_dict)` -> an identity object, each Params or section in it given as `as_dict(section)`: built
    with `params_identity` (today), and as each earlier version built it (`identity_eras`)."""
    met: dict[str, Added] = {}
    today = build(lambda p: _identity_dict(p, frozenset(), frozenset(), met))
    earlier: list[Any] = []
    for obj in build_versions(build)[1:]:
        if obj is not None and obj != today and obj not in earlier:
            earlier.append(obj)
    otherwise: list[tuple[Any, str]] = []
    names = [a.name for a in ADDED]
    # the version before ADDED[k] with today's values of the settings it had; today's with one setting met at its
    # neutral value (an output made at the default, refused for a user's value)
    behaviours = [(frozenset(names[:k]), frozenset(names[k:])) for k in range(len(ADDED))]
    behaviours += [(frozenset(), frozenset({name})) for name in met]
    for keep, absent in behaviours:
        changed = [a for a in ADDED if a.name in absent and a.name in met]
        obj = build(lambda p, keep=keep, absent=absent: _identity_dict(p, keep, absent, {}, strict=False))
        if changed and obj != today and obj not in earlier and obj not in [o for o, _ in otherwise]:
            otherwise.append((obj, otherwise_note(changed)))
    return IdentityVersions(today, earlier, otherwise)



def settings_at_rest(params: Any, read: tuple[str, ...]) -> list[Any]:
    """`params` as an earlier version may have made, with it, an output of a command that reads only `read`
    (`tree.read_params`: section names, the seed, dotted settings) while its identity held every setting: the
    settings it does not read at their defaults, and the registered ones (`ADDED`) among them that the version did
    not have at their neutral values (it behaved as they do). One Params per distinct form, the version with every
    setting first. Such an output is one of `params`, whatever the settings it does not read are now (a map's
    identity held every setting until fix51; check-poses' until fix81)."""
    from .tree import Params

    def reads(name: str) -> bool:
        return name in read or name.partition(".")[0] in read

    default = Params()
    rest: dict[str, Any] = {}
    for f in dataclasses.fields(Params):
        if f.name in read:
            continue
        value = getattr(default, f.name)
        if dataclasses.is_dataclass(value):  # the dotted settings of a section that are read keep their values
            kept = {name.partition(".")[2] for name in read if name.partition(".")[0] == f.name}
            value = dataclasses.replace(value, **{k: getattr(getattr(params, f.name), k) for k in kept})
        rest[f.name] = value
    unread = [a for a in ADDED if not reads(a.name) and a.neutral is not NO_NEUTRAL]
    forms: list[Any] = []
    for k in range(len(unread), -1, -1):  # the version without unread[k:]
        sections = dict(rest)
        for added in unread[k:]:
            name, _, key = added.name.partition(".")
            sections[name] = dataclasses.replace(sections[name], **{key: added.neutral})
        form = dataclasses.replace(params, **sections)
        if form not in forms:
            forms.append(form)
    return forms

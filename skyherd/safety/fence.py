"""Envelope from a geofence uploaded over MAVLink as fence mission items (mission_type FENCE).

Items follow MAVLink's MAV_CMD_NAV_FENCE_* commands:
  5000 RETURN_POINT            lat, lon                      (kept as the recovery anchor)
  5001 POLYGON_VERTEX_INCLUSION param1 = vertex count, param2 = inclusion group
  5002 POLYGON_VERTEX_EXCLUSION param1 = vertex count
  5003 CIRCLE_INCLUSION         param1 = radius [m]
  5004 CIRCLE_EXCLUSION         param1 = radius [m]
A polygon is `param1` consecutive vertex items. Latitude and longitude in degrees (the only
place degrees appear), converted to NED about home. Several inclusion areas are a union.
Items are tuples (command, lat_deg, lon_deg, param1, ...), objects with those attributes, or
the endpoint's stored MISSION_ITEM_INT records (x, y in degrees·1e7).
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
from typing import Any

import numpy as np

from skyherd.flight.geo import Home, geodetic_to_ned
from skyherd.safety.config import check_spec
from skyherd.safety.envelope import Envelope, EnvelopeSpec, Zone, circle_zone, polygon_zone

FENCE_RETURN_POINT = 5000
FENCE_POLYGON_INCLUSION = 5001
FENCE_POLYGON_EXCLUSION = 5002
FENCE_CIRCLE_INCLUSION = 5003
FENCE_CIRCLE_EXCLUSION = 5004


class FenceItemsError(ValueError):
    """Fence items that do not describe a usable fence (bad counts, bad coordinates)."""


def _fields(item: Any) -> tuple[int, float, float, float]:
    """(command, lat_deg, lon_deg, param1) from a tuple or an object with those attributes."""
    if isinstance(item, tuple | list):
        if len(item) < 4:
            raise FenceItemsError(
                f"fence item needs (command, lat, lon, param1, ...), got {item!r}"
            )
        cmd, lat, lon, p1 = item[0], item[1], item[2], item[3]
    elif hasattr(item, "x") and hasattr(item, "y") and not hasattr(item, "lat"):
        # MISSION_ITEM_INT as stored by the MAVLink endpoint: x, y in degrees·1e7
        cmd, p1 = getattr(item, "command", None), getattr(item, "param1", None)
        try:
            lat, lon = int(item.x) / 1e7, int(item.y) / 1e7
        except (TypeError, ValueError) as e:
            raise FenceItemsError(f"fence item with non-numeric x/y: {item!r}") from e
    else:
        cmd = getattr(item, "command", None)
        lat = getattr(item, "lat_deg", getattr(item, "lat", None))
        lon = getattr(item, "lon_deg", getattr(item, "lon", None))
        p1 = getattr(item, "param1", None)
    try:
        return int(cmd), float(lat), float(lon), float(p1)
    except (TypeError, ValueError) as e:
        raise FenceItemsError(f"fence item with non-numeric fields: {item!r}") from e


def envelope_from_fence_items(
    items: list, home: Home, base_envelope: EnvelopeSpec | Envelope
) -> EnvelopeSpec:
    """Replace the fence of `base_envelope` by the uploaded one; keep its dynamics and limits.

    The version becomes `<base version>+fence-<8 hex of the items' hash>` so that runs record
    exactly which uploaded fence they flew. Raises FenceItemsError for unusable items.
    """
    base = base_envelope.spec if isinstance(base_envelope, Envelope) else base_envelope
    sides = base.limits.circle_sides
    inc: list[Zone] = []
    exc: list[Zone] = []
    parsed = [_fields(it) for it in items]
    i = 0
    while i < len(parsed):
        cmd, lat, lon, p1 = parsed[i]
        if not (
            math.isfinite(lat) and math.isfinite(lon) and -90 <= lat <= 90 and -180 <= lon <= 180
        ):
            raise FenceItemsError(f"fence item {i}: latitude/longitude out of range ({lat}, {lon})")
        ne = geodetic_to_ned(home, lat, lon, home.alt_m)[:2]
        if cmd in (FENCE_POLYGON_INCLUSION, FENCE_POLYGON_EXCLUSION):
            n = int(p1)
            if n < 3 or i + n > len(parsed):
                raise FenceItemsError(
                    f"fence item {i}: polygon of {p1:g} vertices, {len(parsed) - i} items left"
                )
            pts = []
            for k in range(i, i + n):
                ck, la, lo, pk = parsed[k]
                if ck != cmd or int(pk) != n:
                    raise FenceItemsError(
                        f"fence item {k}: polygon vertex {k - i + 1}/{n} has command {ck}, count {pk:g}"
                    )
                pts.append(geodetic_to_ned(home, la, lo, home.alt_m)[:2])
            label = "fence" if cmd == FENCE_POLYGON_INCLUSION else "no-fly zone"
            try:
                zone = polygon_zone(
                    f"{label} {len(inc if cmd == FENCE_POLYGON_INCLUSION else exc) + 1}",
                    np.array(pts),
                )
            except ValueError as e:
                raise FenceItemsError(f"fence items {i}-{i + n - 1}: {e}") from e
            (inc if cmd == FENCE_POLYGON_INCLUSION else exc).append(zone)
            i += n
        elif cmd in (FENCE_CIRCLE_INCLUSION, FENCE_CIRCLE_EXCLUSION):
            if not (p1 > 0 and math.isfinite(p1)):
                raise FenceItemsError(f"fence item {i}: circle radius must be > 0 m, got {p1}")
            excl = cmd == FENCE_CIRCLE_EXCLUSION
            lst = exc if excl else inc
            label = "no-fly circle" if excl else "fence circle"
            lst.append(circle_zone(f"{label} {len(lst) + 1} (r {p1:g} m)", ne, p1, sides, excl))
            i += 1
        elif cmd == FENCE_RETURN_POINT:
            i += 1
        else:
            raise FenceItemsError(
                f"fence item {i}: command {cmd} is not a MAV_CMD_NAV_FENCE_* item"
            )
    if not inc and base.limits.home_radius_m <= 0:
        raise FenceItemsError(
            "uploaded fence has no inclusion area and the base set no home radius"
        )
    digest = hashlib.sha256(
        repr([tuple(round(x, 9) for x in p) for p in parsed]).encode()
    ).hexdigest()[:8]
    spec = dataclasses.replace(
        base,
        version=f"{base.version}+fence-{digest}",
        inclusions=tuple(inc) if inc else base.inclusions,
        exclusions=tuple(exc),
        source=f"{len(parsed)} MAVLink fence items over {base.source or base.name}",
    )
    try:
        check_spec(spec)
    except ValueError as e:
        raise FenceItemsError(f"uploaded fence: {e}") from e
    return spec


@dataclasses.dataclass(frozen=True)
class VehicleFenceShape:
    """One area of the envelope's fence in the form the built-in autopilots' `set_fence` takes
    (flight.geofence: kind, inclusion, vertices_ne (k, 2) [m, NED about home])."""

    inclusion: bool
    vertices_ne: np.ndarray
    kind: str = "polygon"
    center_ne: np.ndarray | None = None
    radius: float = 0.0


def vehicle_fence(spec: EnvelopeSpec) -> list[VehicleFenceShape]:
    """The envelope's inclusion fence and exclusion zones (circles as their 16-gons), as the
    vehicle's own fence: what a mission uploads so the autopilot's last line (refusals, breach
    action, a HOLD circle that fits) knows the same boundary as the net."""
    return [VehicleFenceShape(True, z.points.copy()) for z in spec.inclusions] + [
        VehicleFenceShape(False, z.points.copy()) for z in spec.exclusions
    ]

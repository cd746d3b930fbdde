"""The NMEA GPS wire (executive/robotlink/nmea.py): geodesy, parsing, the loopback link.

Geodesy: the airport frame A <-> WGS-84 maps round-trip (hypothesis), match known
lengths of a thousandth of a degree, and put +x along the bearing with +y 90 deg
counter-clockwise. Parsing (no sockets, a fake clock): GGA/GST become a GpsFix in A with
the documented sigma; bad checksums, truncated sentences, garbage and missing fixes give
no fix, are counted and reported as soft status; a silent stream is the one hard fault.
Link: NmeaServer -> NmeaClient over loopback TCP, and the client reconnects after the
server goes away. Waits are bounded polls; nothing asserts how long anything took.
"""

from __future__ import annotations

import datetime as dt
import math
import socket
import time

import pynmea2
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from executive.core.records import GpsFix
from executive.robotlink.nmea import (
    MIN_SIGMA,
    UERE_M,
    GeoReference,
    NmeaClient,
    NmeaDecoder,
    NmeaServer,
    nmea_sentences,
    sigma_from_gst,
    sigma_from_hdop,
)

NOON = dt.datetime(2024, 6, 1, 12, 0, 0, tzinfo=dt.UTC)
GEO = GeoReference(43.6290, 1.3638, 90.0, 150.0)  # an apron near Toulouse, x east
WAIT = 5.0

# The textbook GGA (valid checksum): 48 deg 07.038' N, 11 deg 31.000' E, quality 1, HDOP 0.9
TEXTBOOK_GGA = "$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47"
TEXTBOOK_LAT, TEXTBOOK_LON = 48.0 + 7.038 / 60.0, 11.0 + 31.0 / 60.0


class FakeClock:
    def __init__(self, t: float = 100.0) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


def lines(*sentences: str) -> bytes:
    return "".join(s + "\r\n" for s in sentences).encode("ascii")


def gga(quality: int, lat: str = "4807.038", lon: str = "01131.000", hdop: str = "0.9") -> str:
    fields = ("123519.00", lat, "N" if lat else "", lon, "E" if lon else "", str(quality))
    fields += ("08", hdop, "545.4", "M", "46.9", "M", "", "")
    return str(pynmea2.GGA("GP", "GGA", fields))


def gst(sd_lat: str, sd_lon: str, utc: str = "123519.00") -> str:
    return str(pynmea2.GST("GP", "GST", (utc, "0.5", "0.1", "0.1", "0.0", sd_lat, sd_lon, "0.1")))


def decoder(clock: FakeClock | None = None, geo: GeoReference = GEO) -> NmeaDecoder:
    return NmeaDecoder(geo, clock or FakeClock(), stale_after=2.0, recent=10.0)


def wait_until(predicate, action=None, timeout: float = WAIT) -> bool:
    """Poll ``predicate`` (running ``action`` first each time) for up to ``timeout`` s."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if action is not None:
            action()
        if predicate():
            return True
        time.sleep(0.02)
    return predicate()


# -- geodesy -----------------------------------------------------------------------------------
@settings(max_examples=300, deadline=None)
@given(
    lat0=st.floats(-85.0, 85.0),
    lon0=st.floats(-180.0, 180.0),
    bearing=st.floats(0.0, 360.0),
    altitude=st.floats(-100.0, 4000.0),
    x=st.floats(-5000.0, 5000.0),
    y=st.floats(-5000.0, 5000.0),
)
def test_airport_geodetic_round_trip(lat0, lon0, bearing, altitude, x, y):
    geo = GeoReference(lat0, lon0, bearing, altitude)
    lat, lon = geo.to_geodetic(x, y)
    back = geo.to_airport(lat, lon)
    assert math.hypot(back[0] - x, back[1] - y) < 1e-6  # a micrometre
    again = geo.to_geodetic(*back)
    assert again[0] == pytest.approx(lat, abs=1e-11)
    assert math.remainder(again[1] - lon, 360.0) == pytest.approx(0.0, abs=1e-11)


def test_origin_maps_to_zero():
    assert GEO.to_airport(GEO.latitude_deg, GEO.longitude_deg) == pytest.approx((0, 0), abs=1e-9)
    assert GEO.to_geodetic(0.0, 0.0) == pytest.approx((GEO.latitude_deg, GEO.longitude_deg))


@pytest.mark.parametrize(
    ("lat0", "north_m", "east_m"),
    [
        (0.0, 110.574, 111.320),  # 0.001 deg at the equator (WGS-84 arc lengths)
        (45.0, 111.132, 78.847),
    ],
)
def test_thousandth_of_a_degree_has_its_known_length(lat0, north_m, east_m):
    geo = GeoReference(lat0, 10.0, 90.0)
    assert geo.to_airport(lat0 + 0.001, 10.0) == pytest.approx((0.0, north_m), abs=0.002)
    assert geo.to_airport(lat0, 10.001) == pytest.approx((east_m, 0.0), abs=0.002)


@pytest.mark.parametrize(
    ("bearing", "north_xy", "east_xy"),
    [
        (0.0, (1, 0), (0, -1)),  # x north: y points west
        (90.0, (0, 1), (1, 0)),  # x east, y north: the shipped missions' A
        (180.0, (-1, 0), (0, 1)),  # x south: y points east
        (270.0, (0, -1), (-1, 0)),  # x west: y points south
    ],
)
def test_x_follows_the_bearing_and_y_is_counter_clockwise(bearing, north_xy, east_xy):
    geo = GeoReference(45.0, 10.0, bearing)
    north = geo.to_airport(45.001, 10.0)
    east = geo.to_airport(45.0, 10.001)
    assert north == pytest.approx(tuple(111.132 * c for c in north_xy), abs=0.002)
    assert east == pytest.approx(tuple(78.847 * c for c in east_xy), abs=0.002)


def test_geo_reference_rejects_nonsense():
    with pytest.raises(ValueError, match="finite"):
        GeoReference(math.nan, 0.0, 90.0)
    with pytest.raises(ValueError, match="latitude"):
        GeoReference(90.0, 0.0, 90.0)


# -- parsing -----------------------------------------------------------------------------------
def test_textbook_gga_becomes_a_fix_in_a_with_the_hdop_sigma():
    clock = FakeClock(42.0)
    dec = decoder(clock, GeoReference(TEXTBOOK_LAT, TEXTBOOK_LON, 90.0))
    dec.feed(lines(TEXTBOOK_GGA))
    fix = dec.latest()
    assert fix is not None
    assert fix.stamp == 42.0  # stamped on arrival with the caller's clock
    assert (fix.x, fix.y) == pytest.approx((0.0, 0.0), abs=1e-6)
    assert fix.sigma == pytest.approx(0.9 * UERE_M[1] / math.sqrt(2.0))
    assert dec.counts().fixes == 1
    assert dec.problems == []


def test_gga_position_lands_where_the_geo_reference_puts_it():
    dec = decoder()  # GEO is ~500 km from the textbook point: far, but only a map
    dec.feed(lines(gga(1, lat="4359.0000", lon="00123.0000")))
    fix = dec.latest()
    assert fix is not None
    x, y = GEO.to_airport(43.0 + 59.0 / 60.0, 1.0 + 23.0 / 60.0)
    assert (fix.x, fix.y) == pytest.approx((x, y), abs=1e-6)
    assert fix.y > 0.0  # 43 deg 59' is north of the origin at 43.629 deg


def test_gst_of_the_same_epoch_sets_sigma():
    dec = decoder()
    dec.feed(lines(gst("0.020", "0.040"), gga(4)))
    fix = dec.latest()
    assert fix is not None
    assert fix.sigma == pytest.approx(math.sqrt((0.02**2 + 0.04**2) / 2.0))
    assert fix.sigma == pytest.approx(sigma_from_gst(0.02, 0.04))


def test_gst_of_another_epoch_is_not_used():
    dec = decoder()
    dec.feed(lines(gst("0.020", "0.040", utc="123000.00"), gga(4, hdop="1.5")))
    fix = dec.latest()
    assert fix is not None
    assert fix.sigma == pytest.approx(sigma_from_hdop(1.5, 4))
    assert fix.sigma == pytest.approx(1.5 * 0.02 / math.sqrt(2.0))


def test_sigma_never_reaches_zero():
    assert sigma_from_gst(0.0, 0.0) == MIN_SIGMA
    assert sigma_from_hdop(0.01, 4) == MIN_SIGMA


def test_rmc_and_other_sentences_keep_the_stream_alive_without_a_fix():
    clock = FakeClock()
    dec = decoder(clock)
    rmc = str(pynmea2.RMC("GP", "RMC", ("123519", "A", "4807.038", "N", "01131.000", "E")))
    clock.t += 1.5
    dec.feed(lines(rmc))
    clock.t += 1.5
    assert dec.health() == []  # the last valid sentence is 1.5 s old
    assert dec.latest() is None
    assert dec.counts().sentences == 1


def test_bad_checksums_are_counted_and_reported_softly():
    dec = decoder()
    bad = TEXTBOOK_GGA.replace("*47", "*48")
    dec.feed(lines(bad, bad, bad))
    assert dec.latest() is None
    assert dec.counts().bad_checksum == 3
    assert "GPS: bad NMEA checksum (3 sentences)" in dec.status()
    assert dec.health() == []  # soft: bad lines alone are not a lost stream yet


def test_a_corrupted_field_fails_the_checksum():
    dec = decoder()
    dec.feed(lines(TEXTBOOK_GGA.replace("4807.038", "4817.038")))
    assert dec.latest() is None
    assert dec.counts().bad_checksum == 1


def test_truncated_sentences_are_counted():
    dec = decoder()
    dec.feed(lines(TEXTBOOK_GGA[:30], TEXTBOOK_GGA[:-3]))
    assert dec.latest() is None
    assert dec.counts().truncated == 2
    assert "GPS: truncated NMEA, no checksum (2 sentences)" in dec.status()


def test_garbage_bytes_are_counted_and_the_next_sentence_still_parses():
    dec = decoder()
    dec.feed(b"\xff\xfe\x00\x81garbage\r\nhello world\r\n\x00\x00\x00\n")
    assert dec.latest() is None
    assert dec.counts().garbage == 3
    assert "GPS: unreadable NMEA (3 lines)" in dec.status()
    dec.feed(lines(TEXTBOOK_GGA))
    assert dec.latest() is not None


def test_an_endless_line_is_dropped_as_garbage():
    dec = decoder()
    dec.feed(b"$" + b"A" * 10_000)
    assert dec.counts().garbage == 1
    dec.feed(lines("", TEXTBOOK_GGA))  # the newline ends the junk; the next line is good
    assert dec.latest() is not None


def test_a_sentence_split_across_reads_is_reassembled():
    dec = decoder()
    data = lines(TEXTBOOK_GGA)
    for k in range(0, len(data), 7):
        dec.feed(data[k : k + 7])
    assert dec.latest() is not None
    assert dec.counts().lines == 1


def test_malformed_fields_with_a_valid_checksum_are_counted():
    dec = decoder()
    dec.feed(lines(gga(1, lat="48x7.038"), gga(1, hdop=""), gst("abc", "0.1")))
    assert dec.latest() is None
    assert dec.counts().malformed == 3
    assert "GPS: malformed NMEA fields (3 sentences)" in dec.status()


@pytest.mark.parametrize(
    ("sentence", "quality_text"),
    [
        (gga(0), " (GGA quality 0)"),
        (gga(6), " (GGA quality 6)"),  # dead reckoning is not a GNSS fix
        (gga(1, lat="", lon=""), " (GGA without position)"),
    ],
)
def test_missing_fix_gives_no_fix_and_a_soft_status(sentence, quality_text):
    clock = FakeClock(100.0)
    dec = decoder(clock)
    dec.feed(lines(TEXTBOOK_GGA))
    assert dec.latest() is not None
    for _ in range(12):
        clock.t += 1.0
        dec.feed(lines(sentence))
    assert dec.latest() is None
    assert dec.counts().no_fix == 12
    assert dec.status() == [f"GPS: no fix since 12.0 s{quality_text}"]
    assert dec.health() == []  # no fix is degradable, not a hard fault


def test_a_silent_stream_is_the_hard_fault_and_clears_when_sentences_return():
    clock = FakeClock(0.0)
    dec = decoder(clock)
    assert dec.health() == []
    clock.t = 3.0
    assert dec.health() == ["GPS: NMEA stream lost (no valid sentence for 3.0 s)"]
    dec.feed(b"junk\r\n")  # bytes, but no valid sentence: still lost
    assert dec.health() != []
    dec.feed(lines(TEXTBOOK_GGA))
    assert dec.health() == []
    clock.t = 10.0
    assert dec.latest() is not None  # the old fix stays; its stamp tells its age
    assert "GPS: NMEA stream lost (no valid sentence for 7.0 s)" in dec.health()
    assert "GPS: no fix since 7.0 s" in dec.status()


def test_counted_problems_leave_the_status_when_they_stop():
    clock = FakeClock(0.0)
    dec = decoder(clock)
    dec.feed(lines(TEXTBOOK_GGA.replace("*47", "*00")))
    clock.t = 5.0
    dec.feed(lines(TEXTBOOK_GGA))
    assert "GPS: bad NMEA checksum (1 sentence)" in dec.status()
    clock.t = 10.5
    dec.feed(lines(TEXTBOOK_GGA))
    assert dec.status() == []
    assert dec.counts().bad_checksum == 1  # the total stays


def test_inter_arrival_statistics():
    clock = FakeClock(0.0)
    dec = decoder(clock)
    for t in (0.0, 0.1, 0.2, 0.5):
        clock.t = t
        dec.feed(lines(TEXTBOOK_GGA))
    stats = dec.stats()
    assert stats.fixes.count == 4
    assert stats.fixes.max_interval == pytest.approx(0.3)
    assert stats.fixes.last_interval == pytest.approx(0.3)
    assert stats.fixes.mean_interval == pytest.approx(0.5 / 3)


# -- sentences written for the simulator -------------------------------------------------------
@pytest.mark.parametrize(
    "geo",
    [
        GEO,
        GeoReference(-33.9461, 151.1772, 13.0, 6.0),  # south and east
        GeoReference(40.6413, -73.7781, 301.0, 4.0),  # north and west
        GeoReference(-22.81, -43.25, 200.0, 9.0),  # south and west
    ],
)
def test_published_sentences_decode_to_the_same_fix(geo):
    dec = decoder(geo=geo)
    for x, y, sigma in ((0.0, 0.0, 0.02), (-1234.567, 2345.678, 0.3), (3000.25, -999.75, 2.5)):
        text = nmea_sentences(geo, GpsFix(0.0, x, y, sigma), NOON)
        for sentence in text:
            pynmea2.parse(sentence, check=True)  # well-formed, correct checksum
        dec.feed(lines(*text))
        fix = dec.latest()
        assert fix is not None
        assert math.hypot(fix.x - x, fix.y - y) < 1e-3
        assert fix.sigma == pytest.approx(sigma, abs=1e-4)


def test_no_fix_is_published_as_gga_quality_zero():
    (sentence,) = nmea_sentences(GEO, None, NOON)
    msg = pynmea2.parse(sentence, check=True)
    assert isinstance(msg, pynmea2.GGA)
    assert msg.gps_qual == 0
    dec = decoder()
    dec.feed(lines(sentence))
    assert dec.latest() is None
    assert dec.counts().no_fix == 1


# -- the loopback link -------------------------------------------------------------------------
def published(fix: GpsFix):
    def close_to(got: GpsFix | None) -> bool:
        return got is not None and math.hypot(got.x - fix.x, got.y - fix.y) < 1e-3

    return close_to


def test_server_to_client_over_loopback_tcp():
    fix = GpsFix(0.0, -60.125, 10.5, 0.03)
    with NmeaServer(GEO) as server, NmeaClient(server.url, GEO, time.monotonic) as client:
        assert server.url == f"socket://127.0.0.1:{server.port}"
        close_to = published(fix)
        assert wait_until(
            lambda: close_to(client.latest()), lambda: server.publish(fix, dt.datetime.now(dt.UTC))
        ), client.problems
        got = client.latest()
        assert got is not None
        assert got.sigma == pytest.approx(0.03, abs=1e-4)
        assert client.health() == []
        assert client.stats().fixes.count >= 1

        assert wait_until(
            lambda: client.latest() is None, lambda: server.publish(None, dt.datetime.now(dt.UTC))
        )
        assert any(p.startswith("GPS: no fix since") for p in client.status())
        assert client.health() == []


def test_client_reconnects_after_the_server_goes_away():
    first, second = GpsFix(0.0, 1.0, 2.0, 0.05), GpsFix(0.0, -3.0, 4.0, 0.05)
    server = NmeaServer(GEO)
    port = server.port
    client = NmeaClient(server.url, GEO, time.monotonic, stale_after=0.3)
    try:
        assert wait_until(
            lambda: published(first)(client.latest()),
            lambda: server.publish(first, dt.datetime.now(dt.UTC)),
        )
        server.close()  # the simulator dies
        assert wait_until(lambda: any("NMEA stream lost" in p for p in client.health()))
        server = NmeaServer(GEO, port=port)  # and comes back on the same port
        assert wait_until(
            lambda: published(second)(client.latest()),
            lambda: server.publish(second, dt.datetime.now(dt.UTC)),
        ), client.problems
        assert client.counts().connections >= 2
        assert client.health() == []
    finally:
        client.close()
        server.close()


def test_client_survives_a_dropped_connection():
    fix = GpsFix(0.0, 7.0, -8.0, 0.05)
    with NmeaServer(GEO) as server, NmeaClient(server.url, GEO, time.monotonic) as client:
        assert wait_until(lambda: server.clients == 1)
        server.disconnect_clients()
        assert wait_until(
            lambda: published(fix)(client.latest()),
            lambda: server.publish(fix, dt.datetime.now(dt.UTC)),
        )
        assert client.counts().connections >= 2


def test_server_forgets_a_client_that_left():
    with NmeaServer(GEO) as server:
        client = NmeaClient(server.url, GEO, time.monotonic)
        assert wait_until(lambda: server.clients == 1)
        client.close()
        assert wait_until(
            lambda: server.clients == 0, lambda: server.publish(None, dt.datetime.now(dt.UTC))
        )


def test_nothing_listening_is_a_lost_stream_with_the_reason():
    with socket.socket() as probe:  # a loopback port that was free a moment ago
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    url = f"socket://127.0.0.1:{port}"
    with NmeaClient(url, GEO, time.monotonic, stale_after=0.2) as client:
        assert wait_until(lambda: client.counts().link_errors >= 2)  # it keeps trying
        assert wait_until(lambda: client.health() != [])
        (fault,) = client.health()
        assert fault.startswith("GPS: NMEA stream lost") and url in fault
        assert client.latest() is None

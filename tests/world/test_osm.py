"""The fetch stage's OSM parsing, offline: OSM XML written here and parsed by osmnx; the fallback; an unknown
place answered by a local stand-in for Nominatim. No test needs the network."""

from __future__ import annotations

import json
import threading
from http.server import BaseHTTPRequestHandler, HTTPServer

import numpy as np
import pytest

from replicate.world.osm import OSMUnavailable, fetch_outline, outline_from_osm_xml, query_osm
from replicate.world.regions import RegionError, region_from_file

from ..conftest import ROOT

FALLBACK = ROOT / "data" / "bedok_reservoir_sla.geojson"


def osm_xml(path, rings):
    """An OSM XML file with one closed way per (name, tags, lon/lat ring)."""
    nodes, ways, nid = [], [], 1
    for wid, (name, tags, ring) in enumerate(rings, start=100):
        refs = []
        for lon, lat in ring[:-1]:
            nodes.append(f'  <node id="{nid}" lat="{lat}" lon="{lon}" version="1"/>')
            refs.append(nid)
            nid += 1
        refs.append(refs[0])
        nds = "\n".join(f'    <nd ref="{r}"/>' for r in refs)
        all_tags = {**tags, "name": name}
        tag_xml = "\n".join(f'    <tag k="{k}" v="{v}"/>' for k, v in all_tags.items())
        ways.append(f'  <way id="{wid}" version="1">\n{nds}\n{tag_xml}\n  </way>')
    path.write_text(
        '<?xml version="1.0" encoding="UTF-8"?>\n<osm version="0.6" generator="test">\n'
        + "\n".join(nodes + ways)
        + "\n</osm>\n"
    )
    return path


def square_ring(lon, lat, d):
    return [(lon, lat), (lon + d, lat), (lon + d, lat + d), (lon, lat + d), (lon, lat)]


def test_osm_xml_is_parsed_by_osmnx(tmp_path):
    path = osm_xml(
        tmp_path / "bedok.osm",
        [
            ("Bedok Reservoir", {"natural": "water", "water": "reservoir"}, square_ring(103.92, 1.338, 0.008)),
            ("Small Pond", {"natural": "water"}, square_ring(103.90, 1.33, 0.001)),
            ("Bedok Park", {"leisure": "park"}, square_ring(103.93, 1.34, 0.002)),
        ],
    )
    outline = outline_from_osm_xml(path, "bedok reservoir")
    assert outline.source == "openstreetmap"
    assert outline.osm_id == "way/100"
    assert outline.tags["water"] == "reservoir"
    assert "OpenStreetMap contributors" in outline.attribution
    np.testing.assert_allclose(outline.polygon.bounds, (103.92, 1.338, 103.928, 1.346))
    outline.write(tmp_path / "outline.geojson")
    region = region_from_file(tmp_path / "outline.geojson")
    assert region.utm_crs == "EPSG:32648" and region.area == pytest.approx(9.0)
    assert json.loads((tmp_path / "outline.geojson").read_text())["features"][0]["properties"]["osm_id"] == "way/100"


def test_osm_xml_without_the_named_water_is_refused(tmp_path):
    path = osm_xml(tmp_path / "pond.osm", [("Small Pond", {"natural": "water"}, square_ring(103.9, 1.33, 0.001))])
    with pytest.raises(RegionError, match="no water polygon named 'Bedok Reservoir'.*Small Pond"):
        outline_from_osm_xml(path, "Bedok Reservoir")
    (tmp_path / "junk.osm").write_text("<osm><way")
    with pytest.raises(RegionError, match="cannot be parsed"):
        outline_from_osm_xml(tmp_path / "junk.osm", "Bedok Reservoir")


@pytest.fixture
def osm_endpoint(monkeypatch):
    """Point osmnx at a local endpoint; yields a setter for what the stand-in Nominatim answers."""
    import osmnx as ox

    answer = {"body": "[]"}

    class Handler(BaseHTTPRequestHandler):
        def do_GET(self):  # noqa: N802 - http.server API
            body = answer["body"].encode()
            self.send_response(200)
            self.send_header("Content-Type", "application/json")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args):
            pass

    server = HTTPServer(("127.0.0.1", 0), Handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    monkeypatch.setattr(ox.settings, "nominatim_url", f"http://127.0.0.1:{server.server_port}/")
    monkeypatch.setattr(ox.settings, "overpass_url", f"http://127.0.0.1:{server.server_port}/api")
    monkeypatch.setattr(ox.settings, "overpass_rate_limit", False)
    monkeypatch.setattr(ox.settings, "use_cache", False)
    yield answer
    server.shutdown()


def test_unknown_place_is_an_error_not_a_fallback(osm_endpoint):
    osm_endpoint["body"] = "[]"  # Nominatim: no result
    with pytest.raises(RegionError, match="OpenStreetMap does not know 'Atlantis'"):
        fetch_outline("Atlantis", "Atlantis Lake", {"natural": "water"}, 5, FALLBACK)


def test_unreachable_osm_falls_back_and_says_so(monkeypatch):
    import osmnx as ox

    monkeypatch.setattr(ox.settings, "nominatim_url", "http://127.0.0.1:9/")  # nothing listens on port 9
    with pytest.raises(OSMUnavailable):
        query_osm("Bedok Reservoir, Singapore", "Bedok Reservoir", {"natural": "water"}, 2)
    with pytest.warns(UserWarning, match="could not be reached.*bundled outline"):
        outline = fetch_outline("Bedok Reservoir, Singapore", "Bedok Reservoir", {"natural": "water"}, 2, FALLBACK)
    assert outline.source == "fallback" and outline.osm_id is None
    assert "Singapore Open Data Licence" in outline.attribution
    assert "bundled" in outline.note
    with pytest.raises(OSMUnavailable):  # no fallback given: the caller hears about it
        fetch_outline("Bedok Reservoir, Singapore", "Bedok Reservoir", {"natural": "water"}, 2, None)

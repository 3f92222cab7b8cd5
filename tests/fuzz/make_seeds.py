#!/usr/bin/env python3
"""Writes the binary seed files of tests/fuzz/corpus (PNG, EXR, params.exr, sample chunks, sample
stores) from first principles, so the seeds are small and their construction is visible. The JSON
and mesh seeds are plain text files in the corpus folders. Run from anywhere:
    python3 tests/fuzz/make_seeds.py
"""
import os
import struct
import zlib

CORPUS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "corpus")


def write(target, name, data):
    os.makedirs(os.path.join(CORPUS, target), exist_ok=True)
    with open(os.path.join(CORPUS, target, name), "wb") as f:
        f.write(data)


# ---- PNG ------------------------------------------------------------------------------------
def png_chunk(kind, body):
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))


def png(width, height, bit_depth, colour_type, rows, extra=b""):
    """rows: raw scanline bytes without the filter byte."""
    raw = b"".join(b"\0" + r for r in rows)
    ihdr = struct.pack(">IIBBBBB", width, height, bit_depth, colour_type, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + png_chunk(b"IHDR", ihdr) + extra +
            png_chunk(b"IDAT", zlib.compress(raw)) + png_chunk(b"IEND", b""))


# ---- OpenEXR (uncompressed scanline, FLOAT or HALF channels) ---------------------------------
def exr_attr(name, kind, body):
    return name.encode() + b"\0" + kind.encode() + b"\0" + struct.pack("<i", len(body)) + body


def exr(width, height, channels, pixel_type=2):
    """channels: {name: [values, row-major]}; pixel_type 2 = FLOAT, 1 = HALF."""
    names = sorted(channels)
    chlist = b"".join(n.encode() + b"\0" + struct.pack("<iB3xii", pixel_type, 0, 1, 1) for n in names)
    chlist += b"\0"
    box = struct.pack("<iiii", 0, 0, width - 1, height - 1)
    header = (struct.pack("<ii", 20000630, 2) +
              exr_attr("channels", "chlist", chlist) +
              exr_attr("compression", "compression", b"\0") +
              exr_attr("dataWindow", "box2i", box) +
              exr_attr("displayWindow", "box2i", box) +
              exr_attr("lineOrder", "lineOrder", b"\0") +
              exr_attr("pixelAspectRatio", "float", struct.pack("<f", 1.0)) +
              exr_attr("screenWindowCenter", "v2f", struct.pack("<ff", 0, 0)) +
              exr_attr("screenWindowWidth", "float", struct.pack("<f", 1.0)) + b"\0")
    fmt = "<%de" if pixel_type == 1 else "<%df"
    lines = []
    for y in range(height):
        data = b"".join(struct.pack(fmt % width, *channels[n][y * width:(y + 1) * width]) for n in names)
        lines.append(struct.pack("<ii", y, len(data)) + data)
    offset = len(header) + 8 * height
    table = b""
    for line in lines:
        table += struct.pack("<Q", offset)
        offset += len(line)
    return header + table + b"".join(lines)


# ---- Sample store ---------------------------------------------------------------------------
def crc(b):
    return zlib.crc32(b) & 0xFFFFFFFF


def chunk(first_texel, samples_per_texel):
    offsets = [0]
    for n in samples_per_texel:
        offsets.append(offsets[-1] + n)
    records = b""
    for i in range(offsets[-1]):
        records += struct.pack("<12fI", 0, 0, 1, 0.6, 0, 0.8, 0.3, 0.2, 0.1, 1, 1, 1, i % 4)
    payload = struct.pack("<%dQ" % len(offsets), *offsets) + records
    head = struct.pack("<8sIIIIII QQI8x", b"RFLCSMPL", 1, 64, 52, first_texel,
                       len(samples_per_texel), 0, offsets[-1], len(payload), crc(payload))
    assert len(head) == 60
    return head + struct.pack("<I", crc(head)) + payload


def atlas_bin(width, height, pixels):
    payload = struct.pack("<%dI" % len(pixels), *pixels)
    head = struct.pack("<8sIIIII", b"RFLCATLS", 1, width, height, len(pixels), crc(payload))
    return head + struct.pack("<I", crc(head)) + payload


def store_json(texels, chunk_texels, samples, width, height):
    chunks = (texels + chunk_texels - 1) // chunk_texels
    return ('{"format":"reflcap-samples/1","texels":%d,"chunk_texels":%d,"chunks":%d,'
            '"samples":%d,"capture":"capture.json","split":"train","min_cos":0.05,"images":4,'
            '"geometry":"mesh","atlas":{"width":%d,"height":%d}}'
            % (texels, chunk_texels, chunks, samples, width, height)).encode()


def store_input(json_bytes, atlas, chunk_bytes):
    """sample_store_fuzzer's input: u16 n | store.json | u16 n | atlas.bin | chunk_00000.rcs."""
    return (struct.pack("<H", len(json_bytes)) + json_bytes + struct.pack("<H", len(atlas)) + atlas +
            chunk_bytes)


def main():
    write("png", "grey8_2x2.png", png(2, 2, 8, 0, [b"\x00\xff", b"\x80\x40"]))
    write("png", "rgb16_1x2.png", png(1, 2, 16, 2, [b"\xff\xff\x00\x00\x80\x00", b"\x00\x01\x00\x02\x00\x03"]))
    write("png", "rgba8_2x1.png", png(2, 1, 8, 6, [b"\x10\x20\x30\xff\x40\x50\x60\x00"]))
    plte = png_chunk(b"PLTE", b"\xff\x00\x00\x00\xff\x00") + png_chunk(b"tRNS", b"\x80")
    write("png", "palette_trns.png", png(2, 2, 1, 3, [b"\x40", b"\x80"], plte))
    write("png", "grey2_3x1.png", png(3, 1, 2, 0, [b"\x1b"]))

    write("exr", "rgb_float_2x2.exr", exr(2, 2, {"R": [0, 1, 2, 3], "G": [1, 1, 1, 1], "B": [0.5] * 4}))
    write("exr", "y_half_3x1.exr", exr(3, 1, {"Y": [0.25, 1.0, 65504.0]}, pixel_type=1))
    write("exr", "rgb_nan_inf_1x2.exr", exr(1, 2, {"R": [float("nan"), float("inf")], "G": [0, -1],
                                                   "B": [1e-30, 1e30]}))

    # params.exr for brdf_maps_fuzzer's 8x8 quad atlas: 0 and 1 lobe.
    n = 64
    maps = {"rho_d." + c: [0.5] * n for c in "RGB"}
    write("brdf_maps", "lambert_8x8.exr", exr(8, 8, maps))
    for c in "RGB":
        maps["lobe0.Cx." + c] = [-0.8] * n
        maps["lobe0.Cy." + c] = [-0.8] * n
        maps["lobe0.Cz." + c] = [0.9] * n
        maps["lobe0.n." + c] = [20.0] * n
    write("brdf_maps", "one_lobe_8x8.exr", exr(8, 8, maps))

    # Chunks: the first byte is sample_chunk_fuzzer's "rewrite the CRCs" flag.
    write("sample_chunk", "three_texels.rcs", b"\x00" + chunk(0, [2, 0, 3]))
    write("sample_chunk", "three_texels_fixcrc.rcs", b"\x01" + chunk(0, [2, 0, 3]))
    write("sample_chunk", "empty_texel.rcs", b"\x00" + chunk(7, [0]))

    atlas = atlas_bin(4, 2, [0, 1, 2, 5, 7])
    write("sample_store", "five_texels.bin",
          store_input(store_json(5, 3, 5, 4, 2), atlas, chunk(0, [2, 0, 3])))
    write("sample_store", "one_chunk.bin",
          store_input(store_json(5, 8, 5, 4, 2), atlas, chunk(0, [1, 1, 1, 1, 1])))
    # A linked store of two parts (merge --link): the fuzzer writes the part folder and the
    # fingerprints; "samples" 0 so that the linked store's count equals its parts' sum.
    linked = store_json(5, 8, 0, 4, 2)[:-1] + (
        b',"parts":[{"path":"part","fingerprint":""},{"path":"part","fingerprint":""}]}')
    write("sample_store", "linked_two_parts.bin",
          store_input(linked, atlas, chunk(0, [1, 0, 2, 1, 1])))


if __name__ == "__main__":
    main()

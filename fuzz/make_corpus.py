"""Write the seed corpus, fuzz/corpus/<target>/<name>: `python -m fuzz.make_corpus`.

Seeds are real traffic: docs/protocols.md's reference vectors, lines each side says, the
scenario files. A stream target's input starts with two bytes (fuzz.targets.split): the piece
sizes (0x80: all at once, 0x00: one byte at a time) and the target's choices.
"""

import shutil
from pathlib import Path

from fake_marlin.emulator.protocols.stk500 import encode_message
from fake_marlin.wire import commstack
from fake_marlin.wire.checksums import xor8
from fake_marlin.wire.ultimaker_variants import EVERY_SET, NAMES, parse_variants

ROOT = Path(__file__).resolve().parent.parent
CORPUS = ROOT / "fuzz" / "corpus"
WHOLE, BYTEWISE = b"\x80\x00", b"\x00\x00"  # stream headers: one read, or a byte per read



def lines(*commands: str, start: int = 1) -> bytes:
    """Numbered lines with their checksums, as any Marlin host sends them."""
    out = b""
    for number, command in enumerate(commands, start):
        body = f"N{number} {command}".encode()
        out += body + b"*%d\n" % xor8(body)
    return out


def lab_set(names: str) -> bytes:
    """The first byte of a variant target's input: the set's index in EVERY_SET."""
    return bytes((EVERY_SET.index(parse_variants(names)),))


def lab_packets(names: str, *commands: str, start: int = 0) -> bytes:
    """Packets in the variants' format (docs/protocols.md section 1.1), numbered from start."""
    packet = parse_variants(names).packet
    return b"".join(packet.encode(packet.next_seq(start, n), command.encode())
                    for n, command in enumerate(commands))


PING = bytes.fromhex("031901010101021a0100")  # docs/protocols.md section 3
REQUEST = commstack.encode_packet(commstack.Packet(10, commstack.CommType.REQUEST, b"G28\n"))
RESPONSE = commstack.encode_packet(commstack.Packet(20, commstack.CommType.RESPONSE_SUCCESS, b"v1"))
REPETIER = [bytes.fromhex(h) for h in (  # docs/protocols.md section 2
    "850001001ca2ba", "9d01020001000020410000a04100803b45e586", "83900000050500750048656c6c6f89aa")]

STREAMS: dict[str, dict[str, bytes]] = {
    "marlin_receiver": {
        "vectors": WHOLE + b"N0 M110 N0*125\nN1 G28*18\nN2 M105*37\n",
        "vectors-bytewise": BYTEWISE + b"N0 M110 N0*125\nN1 G28*18\nN2 M105*37\n",
        "cura": b"\x80\x01N1G28*50\n",
        "bad-checksum-then-resend": WHOLE + b"N1 G28*19\n" + lines("G28", "M105"),
        "plain-and-comments": b"\x13\x02G28\nM105 ; temp\n(note) G1 X10 Y20\r\nM112\nM876 S1\n"
        b"G2\x088\\;x\n",
        "sd-write": b"\x80\x08" + lines("M28 a.gco") + b"G1 X1\n" + lines("M29", start=2),
    },
    "ultimaker_receiver": {
        "vectors": WHOLE + bytes.fromhex("ffff0003473238c641ffff01044d313035045a"),
        "vectors-bytewise": BYTEWISE + bytes.fromhex("ffff0003473238c641ffff01044d313035045a"),
        "bad-crc-wrong-seq": b"\x80\x18" + bytes.fromhex("ffff0003473238c642ffff01044d313035045a"),
    },
    "ultimaker_variant_receiver": {  # docs/protocols.md section 1.1's vectors
        "ack-compact": lab_set("ack,compact-oob") + WHOLE + lab_packets("ack", "G28", "M105"),
        "crc8-bytewise": lab_set("crc8") + BYTEWISE + bytes.fromhex("ff0003473238d1"
                                                                     "ff01044d3130353b"),
        "sync-byte-cut": lab_set("sync-byte") + b"\x13\x0a"
        + lab_packets("sync-byte", "G1 X100 Y200")[:9] + lab_packets("sync-byte", "G28", "M105"),
        "7bit-crc8-wrap": lab_set("crc8,7bit") + WHOLE + lab_packets("crc8,7bit", "M105", "M114",
                                                                     start=95),
        "all-bad-check": lab_set(",".join(NAMES)) + b"\x80\x18"
        + bytes.fromhex("1620224732384352") + lab_packets("crc8,sync-byte", "G28", "M105"),
    },
    "repetier_receiver": {
        "vectors": WHOLE + b"".join(REPETIER),
        "vectors-bytewise": BYTEWISE + b"".join(REPETIER),
        "ascii": b"\x80\x01" + lines("M110", "G28", "M105") + b"G1 X1\n",
        "binary-error-resync": b"\x1a\xfc" + REPETIER[0][:-1] + b"\x00" * 32 + REPETIER[0],
    },
    "commstack_receiver": {
        "ping": WHOLE + PING,
        "request-response-noise": b"\x05\x01" + REQUEST + RESPONSE + b"\x00\x07garbage\x00",
    },
    "stk500_receiver": {
        "sign-on": WHOLE + bytes.fromhex("1b0100010e0114"),
        "probe-and-leave": BYTEWISE + bytes.fromhex("1b0100010e0114" "1b0300020eeec03a")
        + encode_message(4, b"\x11") + lines("M110"),
    },
    "g2core_receiver": {  # docs/protocols.md section 7: cncjs's start, a job, the controls
        "cncjs": WHOLE + b"{ej:1}\n{jv:4}\n{qv:1}\n{sv:1}\n{si:200}\n{spe:n}\n"
        b"{sr:{stat:t,line:t,posx:t}}\n{sys:n}\nN1G1X5F600\nN2G1X10\n",
        "controls-bytewise": BYTEWISE + b'{"qr":""}\r\n!~%\n\x05\x04\x18N1 G1*99\nG1 X1*5\n',
        "held": b"\x05\xaaN12G1X5\nG0X1\n{a:.5}\n{toolong:1}\n" + b"x" * 600 + b"\nM30\n",
    },
    "host_g2core_parser": {
        "board": WHOLE + b'{"r":{"fv":0.99,"fb":101.03,"msg":"SYSTEM READY"},"f":[1,0,1]}\n'
        b'{"r":{"n":1},"f":[1,0,12]}\n{"qr":14}\n{"sr":{"stat":5,"posx":0.01}}\n'
        b'{"er":{"fb":101.03,"st":207,"msg":"Kill job - Job killed by ^d"}}\n',
        "noise": BYTEWISE + b'g2core[mm] ok> \n{"r":{},"f":[1,\xff0,8]}\n' + b"[" * 3000 + b"\n",
    },
    "protocol_detector": {
        "marlin": b"\x80\x01\nN0 M110*125\n",
        "ultimaker": b"\x00\x01" + bytes.fromhex("ffff0003473238c641"),
        "repetier": b"\x02\x01\x00\xf0" + REPETIER[0],
        "commstack": b"\x80\x00" + PING,
        "stk500": b"\x80\x01" + bytes.fromhex("1b0100010e0114"),
    },
    "host_marlin_parser": {
        "replies": WHOLE + b"start\necho:PowerUp\nok\nok N1 P15 B3\n"
        b"ok T:20.0 /0.0 B:20.0 /0.0 @:0\n"
        b"Error:checksum mismatch, Last Line: 4\nResend: 5\nok\necho:busy: processing\n"
        b"//action:pause\nX:0.00 Y:0.00 Z:0.00 E:0.00\nError:Printer halted. kill() called!\n",
        "command": b"\x02\x05G1 X10 Y20 (move) F3000",
        "resend-forms": BYTEWISE + b"rs N3\nResend:N:7\nRESEND 2\nwait\n",
    },
    "host_ultimaker_parser": {
        "frames": WHOLE
        + bytes.fromhex("0a6f3035313036380a" "0a6f3030304646380a" "0a713030304639380a")
        + b"ProtoError:Checksum mismatch\nLOG:boot\nWARNING:hot\nok\n",
        "command": b"\x03\x07G1 X10 Y20 F3000",
    },
    "host_ultimaker_variant_parser": {
        "ack-compact-frames": lab_set("ack,compact-oob") + WHOLE
        + b"l:Marlin started; protocol variants: ack,compact-oob\n\nq000F98\n\na050F6A\n"
        b"d:e:not an error\n\no050F..\np:Checksum mismatch\ne:Heater\nw:hot\n\nr000F3E\n",
        "plain-host-hears-a": lab_set("") + WHOLE + b"\na000FAA\nLOG:Marlin started\n",
        "sync-command": lab_set("sync-byte") + b"\x03\x5fG1 X10 Y20 F3000",
        "crc8-7bit-command": lab_set("crc8,7bit") + b"\x03\x07M105",
    },
    "host_repetier_parser": {
        "replies": WHOLE + b"ok 1\r\nskip 3\r\nok\r\n\r\nResend:4\r\nok\r\nwait\r\n"
        b"FIRMWARE_NAME:Repetier_1.0 REPETIER_PROTOCOL:2\r\nError:Wrong checksum\r\n",
        "binary-v1": b"\x01\x04G1 X10 Y20 F3000",
        "binary-v2": b"\x01\x05M117 Hello",
        "ascii": b"\x01\x03M105",
    },
    "commstack_frames": {
        "ping": WHOLE + PING,
        "frames-bytewise": BYTEWISE + PING + REQUEST + RESPONSE,
        "overlong": b"\x80\x00" + b"\x01" * 300 + b"\x00",
    },
}
WHOLE_INPUTS: dict[str, dict[str, bytes]] = {  # targets that take the input as it is
    "repetier_binary": {f"vector-{i}": frame for i, frame in enumerate(REPETIER)},
    "gcode_parser": {
        "move": b"G1 X10 Y20 F3000 ; comment",
        "message": b"M117 Hello (world)",
        "tool": b"T1",
        "lowercase-no-spaces": b"g1x1.5y-.5e+2",
        "file": b"M23 file.gco",
    },
}

# Inputs of the bugs found and reported (fuzz.targets.KNOWN): fuzz/known/<target>/<bug>.
SCENARIO = '[printer]\nprotocol = "marlin"\n'
KNOWN: dict[str, dict[str, bytes]] = {}
# Inputs of the bugs found and fixed: seeds of the corpus from then on, so that every test run
# tries them again.
FIXED = {
    "host_repetier_parser": {  # canonical(): one spelling for T00 and T0, M117's text as read
        "canonical-command-zeros": b"\x80\x04T00",
        "repetier-text-spaces": b"\x80\x05M117  Hello",
    },
    "host_marlin_parser": {  # a line over MAX_LINE in one read, 4,400 digits in its number
        "host-long-line": WHOLE + b"Resend: " + b"9" * 4400 + b"\n",
    },
    "repetier_receiver": {  # N1 G1 X<FLT_MAX>, its checksum right
        "repetier-float-overflow": WHOLE + bytes.fromhex("8d00010001ffff7f7f8e84"),
    },
    "gcode_parser": {
        "canonical-redos": b"G1" + b" X1111111" * 9 + b"!",
        "gcode-huge-code": b"G" + b"9" * 400,
    },
    "scenario_loader": {
        "scenario-bad-pattern": (SCENARIO + '[[fault]]\nkind = "drop"\ndirection = "to-host"\n'
                                 'pattern = "("\n').encode(),
        "scenario-nul-path": (SCENARIO + '[job]\nfile = "a\\u0000b"\n').encode(),
        "scenario-huge-job": (SCENARIO + "[job]\nmoves = 1000000000\n").encode(),
    },
}


def main() -> None:
    for target, seeds in KNOWN.items():
        folder = ROOT / "fuzz" / "known" / target
        folder.mkdir(parents=True, exist_ok=True)
        for name, data in seeds.items():
            (folder / name).write_bytes(data)
    for target, seeds in [*STREAMS.items(), *WHOLE_INPUTS.items(), *FIXED.items()]:
        folder = CORPUS / target
        folder.mkdir(parents=True, exist_ok=True)
        for name, data in seeds.items():
            (folder / name).write_bytes(data)
    folder = CORPUS / "scenario_loader"
    folder.mkdir(parents=True, exist_ok=True)
    for path in sorted((ROOT / "scenarios").glob("*.toml")):
        shutil.copy(path, folder / path.name)


if __name__ == "__main__":
    main()

/* rollbot_link.h - the robot link's wire protocol, robot side: COBS frames of checksummed messages.
 *
 * The same protocol as rollbot_oc/robot/protocol.py (its docstring and docs/robot_link.md give the
 * layout byte by byte); a test checks that both sides decode what the other encodes, byte for byte.
 *
 * A frame: COBS(packet) then one 0x00 delimiter.  Packet, little-endian:
 *   version u8 | type u8 | seq u16 | payload length u16 | payload | CRC-32 (IEEE) of all before it.
 *
 * C99, no heap, no stdio: every function works in the caller's buffers.  Doubles go on the wire as
 * IEEE-754 binary64, little-endian; the target's double must be 64 bits (checked at compile time:
 * on AVR, build with -mdouble=64).
 *
 * Use, on a UART:
 *     static rl_decoder_t dec;  rl_decoder_init(&dec);
 *     in the receive loop, for each byte b:  if (rl_decoder_push(&dec, b, &msg) == 1) { use msg; }
 *     to send:  n = rl_encode(&msg, buf, sizeof buf);  if (n > 0) uart_write(buf, n);
 */
#ifndef ROLLBOT_LINK_H
#define ROLLBOT_LINK_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define RL_VERSION 1
#define RL_HEADER_BYTES 6
#define RL_CRC_BYTES 4
#define RL_MAX_PAYLOAD 244                                   /* a packet is at most 254 bytes */
#define RL_MAX_PACKET (RL_HEADER_BYTES + RL_MAX_PAYLOAD + RL_CRC_BYTES)
#define RL_MAX_ENCODED (RL_MAX_PACKET + RL_MAX_PACKET / 254 + 1) /* COBS of a packet, at most (256) */
#define RL_SEQ_WINDOW 32u /* sequence numbers behind the highest that the decoder remembers */
#define RL_MAX_FRAME (RL_MAX_ENCODED + 1)                    /* with its delimiter: size send buffers so */
#define RL_PLAN_HEADER_BYTES 6
#define RL_MAX_CHUNK (RL_MAX_PAYLOAD - RL_PLAN_HEADER_BYTES)  /* plan bytes in one PLAN_CHUNK (238) */
#define RL_STATE_SIZE 11

/* Message types (the type byte). */
enum {
    RL_HEARTBEAT = 1,
    RL_MEASUREMENT = 2,
    RL_COMMAND = 3,
    RL_PLAN_CHUNK = 4,
    RL_MODE = 5
};

/* Results: >= 0 success (a length where one is returned), < 0 the reason a frame is dropped. */
enum {
    RL_OK = 0,
    RL_ERR_COBS = -1,     /* not a COBS encoding */
    RL_ERR_CRC = -2,      /* CRC mismatch */
    RL_ERR_LENGTH = -3,   /* packet too short, or its length field does not match */
    RL_ERR_VERSION = -4,  /* another protocol version */
    RL_ERR_TYPE = -5,     /* unknown message type */
    RL_ERR_PAYLOAD = -6,  /* payload of the wrong size or with invalid fields */
    RL_ERR_OVERFLOW = -7, /* more than RL_MAX_ENCODED bytes without a delimiter */
    RL_ERR_BUFFER = -8    /* the caller's output buffer is too small (encoding) */
};

typedef struct {
    uint32_t time_ms;  /* the sender's clock, ms (wraps) */
    uint8_t mode;      /* the sender's mode code */
} rl_heartbeat_t;

typedef struct {
    uint32_t period;               /* control period index */
    double time;                   /* time of the measurement, s */
    double state[RL_STATE_SIZE];   /* x, y [m]; qw, qx, qy, qz; wx, wy, wz [rad/s]; theta [rad]; theta_dot [rad/s]
                                      (single precision on the wire) */
} rl_measurement_t;

typedef struct {
    uint32_t period;      /* the control period it applies to */
    double acceleration;  /* motor acceleration, rad/s^2 */
    uint8_t status;       /* the controller's status code */
} rl_command_t;

typedef struct {
    uint16_t plan_id;
    uint16_t index;   /* 0 <= index < count */
    uint16_t count;   /* >= 1 */
    uint16_t length;  /* bytes in data, <= RL_MAX_CHUNK */
    uint8_t data[RL_MAX_CHUNK];
} rl_plan_chunk_t;

typedef struct {
    uint8_t mode;    /* the new mode's code */
    uint32_t tick;   /* the control period it took effect */
    uint8_t reason;  /* the reason's code */
} rl_mode_t;

typedef struct {
    uint8_t type;  /* RL_HEARTBEAT .. RL_MODE */
    uint16_t seq;  /* sequence number */
    union {
        rl_heartbeat_t heartbeat;
        rl_measurement_t measurement;
        rl_command_t command;
        rl_plan_chunk_t plan_chunk;
        rl_mode_t mode;
    } body;
} rl_message_t;

/* Streaming decoder: give it the received bytes one at a time.  Counters by reason, as the Python side. */
typedef struct {
    uint8_t buf[RL_MAX_ENCODED];
    uint16_t len;
    uint8_t discarding;  /* an overflowed frame is skipped up to the next delimiter */
    uint8_t have_seq;
    uint16_t last_seq;
    uint32_t frames;     /* frames decoded */
    uint32_t missed;     /* sequence numbers skipped ahead of the highest decoded */
    uint32_t late;       /* frames decoded after a later-numbered one (reordered, delayed) */
    uint32_t duplicates; /* sequence numbers decoded again (within the last RL_SEQ_WINDOW) */
    uint32_t seen;       /* bit i: sequence number last_seq - i decoded */
    uint32_t err_cobs, err_crc, err_length, err_version, err_type, err_payload, err_overflow;
} rl_decoder_t;

/* CRC-32 (IEEE 802.3, reflected 0xEDB88320, init and final XOR 0xFFFFFFFF; zlib's crc32). */
uint32_t rl_crc32(const uint8_t *data, size_t n);

/* COBS encoding of n bytes into out (no delimiter); its length, or RL_ERR_BUFFER if cap is too small.
 * The encoding is at most n + n / 254 + 1 bytes. */
int32_t rl_cobs_encode(const uint8_t *in, size_t n, uint8_t *out, size_t cap);

/* COBS decoding of n bytes (no delimiter) into out; its length, RL_ERR_COBS or RL_ERR_BUFFER. */
int32_t rl_cobs_decode(const uint8_t *in, size_t n, uint8_t *out, size_t cap);

/* The frame of msg (COBS packet and 0x00 delimiter) in out; its length, RL_ERR_TYPE, RL_ERR_PAYLOAD
 * (a plan chunk with invalid fields) or RL_ERR_BUFFER.  A buffer of RL_MAX_FRAME bytes always suffices. */
int32_t rl_encode(const rl_message_t *msg, uint8_t *out, size_t cap);

/* The message of one frame (its COBS bytes, without the delimiter): RL_OK or an RL_ERR_*. */
int32_t rl_decode_frame(const uint8_t *frame, size_t n, rl_message_t *msg);

void rl_decoder_init(rl_decoder_t *dec);

/* Take one received byte: 1 when it completes a frame that decodes (then *msg holds it), 0 otherwise
 * (a dropped frame is counted).  Never fails on any input. */
int rl_decoder_push(rl_decoder_t *dec, uint8_t byte, rl_message_t *msg);

/* Frames dropped, all reasons together. */
uint32_t rl_decoder_dropped(const rl_decoder_t *dec);

#ifdef __cplusplus
}
#endif

#endif /* ROLLBOT_LINK_H */

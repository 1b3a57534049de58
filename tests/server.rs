//! The service end to end on loopback: gRPC streams and HTTP frames give bit for bit what
//! filtering in process gives; 8 sessions at once do not mix; bad input gets the right
//! status with a message naming the problem and leaves the session working; the memory
//! budget, idle eviction and reconnect-by-id hold.

mod common;

use afterimage::filters::create;
use afterimage::frame::{Frame, Plane, Rgb};
use afterimage::io::{write_exr_bytes, Compression, Precision, WriteOptions};
use afterimage::pipeline::run_sequence;
use afterimage::scene::{Jitter, Scene, Settings};
use afterimage::server::client::{Client, SendOptions};
use afterimage::server::proto::{self as pb, frame_chunk};
use afterimage::server::{start, Config, Running};
use serde_json::Value;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tonic::Code;

fn frames(scene: &str, n: u64, seed: u64) -> Vec<Frame> {
    frames_shaded(scene, n, seed, 1)
}

/// Scene frames with one colour sample per `shading x shading` block (1: every pixel).
fn frames_shaded(scene: &str, n: u64, seed: u64, shading: u32) -> Vec<Frame> {
    let s = Settings {
        width: 64,
        height: 36,
        frames: n,
        spp: 4,
        jitter: if shading > 1 {
            Jitter::None
        } else {
            Jitter::Halton(8)
        },
        noise: false,
        seed,
        shading,
    };
    let sc = Scene::new(scene, s).unwrap();
    (0..n).map(|i| sc.frame(i)).collect()
}

fn in_process(filter: &str, frames: &[Frame]) -> Vec<Rgb> {
    let mut f = create(filter, &Default::default()).unwrap();
    run_sequence(f.as_mut(), frames)
        .unwrap()
        .into_iter()
        .map(|o| o.color)
        .collect()
}

fn f16_round(frames: &[Frame]) -> Vec<Frame> {
    let q = |p: &Plane<f32>| {
        Plane::from_fn(p.width(), p.height(), |x, y| {
            half::f16::from_f32(p.get(x, y)).to_f32()
        })
    };
    frames
        .iter()
        .map(|f| {
            let mut g = Frame::new(f.color().clone().map(|p| q(&p))).unwrap();
            g.meta = f.meta.clone();
            for kind in [
                afterimage::frame::ChannelKind::Depth,
                afterimage::frame::ChannelKind::Motion,
                afterimage::frame::ChannelKind::MotionNext,
            ] {
                if let Some(planes) = f.planes(kind) {
                    g.set_f32(kind, planes.iter().map(q).collect()).unwrap();
                }
            }
            if let Some(ids) = f.object_id() {
                g.set_object_id(ids.clone()).unwrap();
            }
            g
        })
        .collect()
}

async fn server(tweak: impl FnOnce(&mut Config)) -> Running {
    let mut c = Config {
        grpc_addr: "127.0.0.1:0".into(),
        http_addr: "127.0.0.1:0".into(),
        ..Config::default()
    };
    tweak(&mut c);
    start(c).await.unwrap()
}

async fn client(r: &Running) -> Client {
    Client::connect(format!("http://{}", r.grpc_addr)).await.unwrap()
}

async fn open(c: &mut Client, filter: &str) -> pb::Session {
    c.inner
        .create_session(session_req(filter))
        .await
        .unwrap()
        .into_inner()
}

fn session_req(filter: &str) -> pb::CreateSessionRequest {
    pb::CreateSessionRequest {
        filter: filter.into(),
        width: 64,
        height: 36,
        ..Default::default()
    }
}

const F32: SendOptions = SendOptions {
    sample: pb::SampleType::F32,
    compression: pb::Compression::None,
    reference: true,
    in_flight: 2,
    shared_memory: false,
};

async fn stream_all(
    c: &mut Client,
    s: &pb::Session,
    frames: &[Frame],
    opts: SendOptions,
) -> Result<Vec<Rgb>, tonic::Status> {
    let mut out = Vec::new();
    c.stream(s, frames.to_vec(), opts, |r| out.push(r.color)).await?;
    Ok(out)
}

fn same(a: &[Rgb], b: &[Rgb], what: &str) {
    assert_eq!(a.len(), b.len(), "{what}: frame count");
    for (i, (x, y)) in a.iter().zip(b).enumerate() {
        for c in 0..3 {
            let (xd, yd) = (x[c].data(), y[c].data());
            let bits = |d: &[f32]| d.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
            assert!(bits(xd) == bits(yd), "{what}: frame {i} channel {c} differs");
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn grpc_streams_are_bit_identical_to_in_process_filtering() {
    let r = server(|_| {}).await;
    let mut c = client(&r).await;
    let fr = frames("moving-sphere", 6, 1);
    // pixel_trace looks 8 frames ahead: every reply comes when the client closes its side.
    for filter in ["taa", "phlm", "pixel_trace"] {
        let s = open(&mut c, filter).await;
        assert_eq!(s.id.len(), 32);
        assert_eq!(s.lookahead, if filter == "pixel_trace" { 8 } else { 0 });
        let got = stream_all(&mut c, &s, &fr, F32).await.unwrap();
        same(&got, &in_process(filter, &fr), filter);
        // zstd on the wire changes nothing.
        let s = open(&mut c, filter).await;
        let opts = SendOptions {
            compression: pb::Compression::Zstd,
            ..F32
        };
        same(
            &stream_all(&mut c, &s, &fr, opts).await.unwrap(),
            &in_process(filter, &fr),
            "zstd",
        );
        // One frame at a time, and more frames ahead than the server takes in (it receives
        // one while it filters another): the same colour.
        for in_flight in [1, 4] {
            let s = open(&mut c, filter).await;
            let opts = SendOptions { in_flight, ..F32 };
            same(
                &stream_all(&mut c, &s, &fr, opts).await.unwrap(),
                &in_process(filter, &fr),
                &format!("{filter}, {in_flight} in flight"),
            );
        }
        // f16 on the wire: the same as filtering f16-rounded frames, rounded to f16.
        let s = open(&mut c, filter).await;
        let opts = SendOptions {
            sample: pb::SampleType::F16,
            ..F32
        };
        let want: Vec<Rgb> = in_process(filter, &f16_round(&fr))
            .into_iter()
            .map(|rgb| {
                let mut f = Frame::new(rgb).unwrap();
                f = f16_round(std::slice::from_ref(&f)).remove(0);
                f.into_color()
            })
            .collect();
        same(&stream_all(&mut c, &s, &fr, opts).await.unwrap(), &want, "f16");
        let info = c
            .inner
            .get_session(pb::GetSessionRequest { id: s.id.clone() })
            .await
            .unwrap()
            .into_inner();
        assert_eq!(info.frames, 6);
    }
    // Sparse shading (one pixel per 2x2 block) travels with its pattern; upsample
    // reconstructs it as in process, and a filter that needs every pixel refuses it.
    let sparse = frames_shaded("moving-sphere", 6, 1, 2);
    let s = open(&mut c, "upsample").await;
    same(
        &stream_all(&mut c, &s, &sparse, F32).await.unwrap(),
        &in_process("upsample", &sparse),
        "upsample, sparse frames",
    );
    let s = open(&mut c, "taa").await;
    let e = stream_all(&mut c, &s, &sparse, F32).await.unwrap_err();
    assert!(e.to_string().contains("shades one pixel per 2x2 block"), "{e}");
    // The reference travels with scene frames: the report has PSNR and SSIM.
    let s = open(&mut c, "taa").await;
    let mut reports = Vec::new();
    c.stream(&s, fr.clone(), F32, |r| reports.push(r.report))
        .await
        .unwrap();
    assert!(reports
        .iter()
        .all(|r| r.psnr.is_some_and(|p| p > 10.0) && r.ssim.is_some()));
    assert!(reports[1]
        .stages
        .iter()
        .any(|st| st.name == "reproject" && st.ms.is_some()));
    r.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn eight_sessions_at_once_do_not_mix() {
    let r = server(|_| {}).await;
    let mut tasks = Vec::new();
    for k in 0..8u64 {
        let mut c = client(&r).await;
        tasks.push(tokio::spawn(async move {
            let filter = if k % 2 == 0 { "taa" } else { "phlm" };
            let scene = ["flyover", "foliage", "fence", "spokes"][(k / 2) as usize];
            let fr = frames(scene, 4, k);
            let s = open(&mut c, filter).await;
            let got = stream_all(&mut c, &s, &fr, F32).await.unwrap();
            same(
                &got,
                &in_process(filter, &fr),
                &format!("session {k} ({filter} on {scene})"),
            );
        }));
    }
    for t in tasks {
        t.await.unwrap();
    }
    assert_eq!(r.service.sessions.totals().sessions, 8);
    r.shutdown().await.unwrap();
}

/// Sends raw chunks on a new stream and returns the first error status.
async fn raw_stream(c: &mut Client, parts: Vec<frame_chunk::Part>) -> tonic::Status {
    let msgs: Vec<pb::FrameChunk> = parts
        .into_iter()
        .map(|p| pb::FrameChunk { part: Some(p) })
        .collect();
    let mut replies = c
        .inner
        .stream(tokio_stream::iter(msgs))
        .await
        .unwrap()
        .into_inner();
    loop {
        match replies.message().await {
            Err(s) => return s,
            Ok(Some(_)) => continue,
            Ok(None) => return tonic::Status::ok("the stream ended without an error"),
        }
    }
}

/// `Stream` is read from the HTTP/2 frames by the server's own route (`stream_route`), not
/// by tonic: a message it cannot take, here one with its compression flag set, sent over a
/// bare HTTP/2 connection, ends the call with the route's status naming why.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_stream_call_reads_its_own_framing_and_names_what_is_wrong() {
    use prost::Message;
    let r = server(|_| {}).await;
    let tcp = tokio::net::TcpStream::connect(r.grpc_addr).await.unwrap();
    let (mut h2, conn) = h2::client::handshake(tcp).await.unwrap();
    tokio::spawn(conn);
    let path = afterimage::server::stream_route::STREAM_PATH;
    let req = http::Request::post(format!("http://{}{path}", r.grpc_addr))
        .header("content-type", "application/grpc")
        .header("te", "trailers")
        .body(())
        .unwrap();
    let (resp, mut send) = h2.send_request(req, false).unwrap();
    let msg = pb::FrameChunk {
        part: Some(frame_chunk::Part::Data(pb::DataChunk {
            data: vec![1; 8].into(),
        })),
    }
    .encode_to_vec();
    let mut framed = vec![1u8];
    framed.extend((msg.len() as u32).to_be_bytes());
    framed.extend(msg);
    send.send_data(framed.into(), true).unwrap();
    let resp = resp.await.unwrap();
    assert_eq!(resp.status(), 200);
    let mut body = resp.into_body();
    while let Some(d) = body.data().await {
        d.unwrap();
    }
    let trailers = body.trailers().await.unwrap().expect("a status in trailers");
    let status = tonic::Status::from_header_map(&trailers).unwrap();
    assert_eq!(status.code(), Code::Internal, "{}", status.message());
    assert!(
        status.message().contains("compression flag 1"),
        "{}",
        status.message()
    );
    r.shutdown().await.unwrap();
}

fn frame_parts(
    frame: &Frame,
    id: &str,
    channels: &[afterimage::frame::ChannelKind],
) -> Vec<frame_chunk::Part> {
    let (h, chunks) = afterimage::server::wire::encode_frame(
        frame,
        id,
        afterimage::frame::ChannelSet::of(channels),
        pb::SampleType::F32,
        pb::Compression::None,
        1 << 20,
    );
    std::iter::once(frame_chunk::Part::Header(h))
        .chain(chunks.into_iter().map(frame_chunk::Part::Data))
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_input_gets_a_precise_status_and_the_session_keeps_working() {
    use afterimage::frame::ChannelKind::{Color, Depth};
    let r = server(|_| {}).await;
    let mut c = client(&r).await;
    let fr = frames("flyover", 3, 1);
    let s = open(&mut c, "taa").await;
    let with = |f: &mut pb::CreateSessionRequest, k: &str, v: &str| {
        f.params.insert(k.into(), v.into());
    };
    // Session creation.
    let mut unknown_param = session_req("taa");
    with(&mut unknown_param, "alhpa", "0.2");
    let mut out_of_bounds = session_req("taa");
    with(&mut out_of_bounds, "alpha", "7");
    let creates: Vec<(&str, pb::CreateSessionRequest, Code, &[&str])> = vec![
        (
            "unknown filter",
            session_req("nope"),
            Code::InvalidArgument,
            &["filter", "nope", "phlm"],
        ),
        (
            "unknown param",
            unknown_param,
            Code::InvalidArgument,
            &["alhpa", "alpha"],
        ),
        (
            "param out of bounds",
            out_of_bounds,
            Code::InvalidArgument,
            &["alpha", "7"],
        ),
        (
            "zero width",
            pb::CreateSessionRequest {
                width: 0,
                ..session_req("taa")
            },
            Code::InvalidArgument,
            &["width", "got 0"],
        ),
        (
            "unknown motion",
            pb::CreateSessionRequest {
                motion: "maya".into(),
                ..session_req("taa")
            },
            Code::InvalidArgument,
            &["motion", "maya", "blender"],
        ),
        (
            "needed channel not declared",
            pb::CreateSessionRequest {
                channels: vec!["depth".into()],
                ..session_req("taa")
            },
            Code::InvalidArgument,
            &["channels", "color"],
        ),
    ];
    for (what, req, code, words) in creates {
        let e = c.inner.create_session(req).await.unwrap_err();
        assert_eq!(e.code(), code, "{what}: {}", e.message());
        for w in words {
            assert!(e.message().contains(w), "{what}: {:?} lacks {w:?}", e.message());
        }
    }
    // Frames.
    let small = frames("flyover", 1, 1).remove(0);
    let small = {
        let cut = |p: &Plane<f32>| Plane::from_fn(32, 18, |x, y| p.get(x, y));
        let mut f = Frame::new(small.color().clone().map(|p| cut(&p))).unwrap();
        f.meta = small.meta.clone();
        f
    };
    let mut nan = fr[0].clone();
    for p in nan.color_mut() {
        p.fill(f32::NAN);
    }
    let closed = open(&mut c, "taa").await;
    c.inner
        .close_session(pb::CloseSessionRequest {
            id: closed.id.clone(),
        })
        .await
        .unwrap();
    let data = frame_chunk::Part::Data(pb::DataChunk {
        data: vec![0; 16].into(),
    });
    let closed_words = [closed.id.as_str()];
    let streams: Vec<(&str, Vec<frame_chunk::Part>, Code, &[&str])> = vec![
        (
            "size mismatch",
            frame_parts(&small, &s.id, &[Color]),
            Code::InvalidArgument,
            &["color", "expected 27648 bytes", "got 6912"],
        ),
        (
            "missing colour",
            {
                let depth = afterimage::server::wire::encode_planes(
                    &[fr[0].planes(Depth).unwrap()[0].data()],
                    pb::SampleType::F32,
                    pb::Compression::None,
                );
                let h = pb::FrameHeader {
                    session_id: s.id.clone(),
                    channels: vec![pb::ChannelHeader {
                        name: "depth".into(),
                        sample: pb::SampleType::F32 as i32,
                        compression: 0,
                        byte_length: depth.len() as u64,
                    }],
                    ..Default::default()
                };
                vec![
                    frame_chunk::Part::Header(h),
                    frame_chunk::Part::Data(pb::DataChunk { data: depth.into() }),
                ]
            },
            Code::InvalidArgument,
            &["no color channel"],
        ),
        (
            "jitter not a number",
            {
                let mut p = frame_parts(&fr[0], &s.id, &[Color]);
                if let Some(frame_chunk::Part::Header(h)) = p.first_mut() {
                    h.jitter_x = f32::NAN;
                }
                p
            },
            Code::InvalidArgument,
            &["jitter", "-1..=1"],
        ),
        (
            "data before header",
            vec![data.clone()],
            Code::InvalidArgument,
            &["out of order", "data before"],
        ),
        (
            "header while a frame is incomplete",
            {
                let mut p = frame_parts(&fr[0], &s.id, &[Color]);
                p.truncate(1);
                p.extend(frame_parts(&fr[1], &s.id, &[Color]));
                p
            },
            Code::InvalidArgument,
            &["out of order", "frame 1", "frame 0"],
        ),
        (
            "closed session",
            frame_parts(&fr[0], &closed.id, &[Color]),
            Code::NotFound,
            &closed_words,
        ),
        (
            "NaN flood",
            frame_parts(&nan, &s.id, &[Color]),
            Code::InvalidArgument,
            &["color", "NaN", "100.0%"],
        ),
        (
            "chunk over max_chunk_bytes",
            {
                let mut p = frame_parts(&fr[0], &s.id, &[Color]);
                p.truncate(1);
                p.push(frame_chunk::Part::Data(pb::DataChunk {
                    data: vec![0; (1 << 20) + 1].into(),
                }));
                p
            },
            Code::ResourceExhausted,
            &["chunk of 1048577 bytes", "the limit is 1048576"],
        ),
        (
            "undeclared channel",
            frame_parts(&fr[0], &s.id, &[Color, afterimage::frame::ChannelKind::Albedo]),
            Code::InvalidArgument,
            &["albedo", "not declared"],
        ),
    ];
    for (what, parts, code, words) in streams {
        let e = raw_stream(&mut c, parts).await;
        assert_eq!(e.code(), code, "{what}: {}", e.message());
        for w in words {
            assert!(e.message().contains(w), "{what}: {:?} lacks {w:?}", e.message());
        }
        // The session still works and its history is untouched by the refused frame.
        let info = c
            .inner
            .get_session(pb::GetSessionRequest { id: s.id.clone() })
            .await
            .unwrap()
            .into_inner();
        assert_eq!(info.frames, 0, "{what}");
    }
    let got = stream_all(&mut c, &s, &fr, F32).await.unwrap();
    same(&got, &in_process("taa", &fr), "after the bad input");
    let metrics = r.service.metrics.render(r.service.sessions.totals());
    assert!(
        metrics.contains("afterimage_errors_total{reason=\"invalid_argument\"}"),
        "{metrics}"
    );
    r.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn memory_budget_idle_eviction_and_reconnect() {
    // A 64x36 phlm session reserves its state, 224 B/px = 516,096 bytes, and the planes of
    // one decoded frame its next frame decodes into (colour, depth, motion and a
    // reference in f32: 82,944) = 599,040; a 2 MiB budget fits three and leaves 300,032.
    let r = server(|c| {
        c.memory_budget_mib = 2;
        c.idle_timeout_s = 2;
    })
    .await;
    let mut c = client(&r).await;
    let a = open(&mut c, "phlm").await;
    let others: Vec<_> = {
        let mut v = Vec::new();
        for _ in 0..2 {
            v.push(open(&mut c, "phlm").await);
        }
        v
    };
    let e = c.inner.create_session(session_req("phlm")).await.unwrap_err();
    assert_eq!(e.code(), Code::ResourceExhausted);
    assert!(
        e.message()
            .contains("needs 599040 bytes; 300032 of the 2097152 bytes of the memory budget are free"),
        "{}",
        e.message()
    );
    c.inner
        .close_session(pb::CloseSessionRequest {
            id: others[0].id.clone(),
        })
        .await
        .unwrap();
    // Reconnect by id: two frames on one stream, the third on a new connection.
    let fr = frames("flyover", 3, 1);
    stream_all(&mut c, &a, &fr[..2], F32).await.unwrap();
    let mut c2 = client(&r).await;
    let third = stream_all(&mut c2, &a, &fr[2..], F32).await.unwrap();
    same(&third, &in_process("phlm", &fr)[2..], "after reconnecting");
    // Idle sessions are evicted; their budget is free again.
    tokio::time::sleep(std::time::Duration::from_millis(3500)).await;
    let e = c
        .inner
        .get_session(pb::GetSessionRequest { id: a.id.clone() })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::NotFound);
    assert!(e.message().contains("evicted"), "{}", e.message());
    assert_eq!(r.service.sessions.totals().sessions, 0);
    c.inner.create_session(session_req("phlm")).await.unwrap();
    r.shutdown().await.unwrap();
}

/// The colour of an EXR reply body.
fn exr_color(body: &[u8]) -> Rgb {
    afterimage::io::read_exr_frame_bytes(body, std::path::Path::new("reply"), &Default::default())
        .unwrap()
        .into_color()
}

/// Flushes session `id` over HTTP until 204: each output's reply (200) headers and body.
async fn flush_all(addr: std::net::SocketAddr, id: &str) -> Vec<(String, Vec<u8>)> {
    let mut out = Vec::new();
    loop {
        let (st, headers, body) = http(
            addr,
            "POST",
            &format!("/v1/sessions/{id}/flush"),
            b"",
            "text/plain",
        )
        .await;
        if st == 204 {
            return out;
        }
        assert_eq!(st, 200, "{}", String::from_utf8_lossy(&body));
        out.push((headers, body));
    }
}

/// `POST /v1/sessions/{id}/frames` with an EXR body.
async fn post_frame(addr: std::net::SocketAddr, id: &str, exr: &[u8]) -> (u16, String, Vec<u8>) {
    http(
        addr,
        "POST",
        &format!("/v1/sessions/{id}/frames"),
        exr,
        "image/x-exr",
    )
    .await
}

/// A minimal HTTP/1.1 exchange over a real socket.
async fn http(
    addr: std::net::SocketAddr,
    method: &str,
    path: &str,
    body: &[u8],
    ctype: &str,
) -> (u16, String, Vec<u8>) {
    http_with(addr, method, path, &format!("Content-Type: {ctype}\r\n"), body).await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn http_frames_are_bit_identical_too() {
    let r = server(|_| {}).await;
    let addr = r.http_addr;
    let (st, _, body) = http(
        addr,
        "POST",
        "/v1/sessions",
        br#"{"filter":"taa","width":64,"height":36}"#,
        "application/json",
    )
    .await;
    assert_eq!(st, 201, "{}", String::from_utf8_lossy(&body));
    let s: Value = serde_json::from_slice(&body).unwrap();
    let id = s["id"].as_str().unwrap().to_string();
    let fr = frames("fence", 4, 1);
    let want = in_process("taa", &fr);
    let opts = WriteOptions {
        precision: Precision::F32,
        compression: Compression::Zip,
    };
    for (i, f) in fr.iter().enumerate() {
        let exr = write_exr_bytes(f, &opts).unwrap();
        let (st, headers, body) = post_frame(addr, &id, &exr).await;
        assert_eq!(st, 200, "{}", String::from_utf8_lossy(&body));
        assert!(
            headers.to_ascii_lowercase().contains("x-afterimage-record: {"),
            "{headers}"
        );
        same(
            &[exr_color(&body)],
            &[want[i].clone()],
            &format!("http frame {i}"),
        );
    }
    // Sparse shading in an EXR body (the pattern is an attribute) to upsample.
    let (st, _, body) = http(
        addr,
        "POST",
        "/v1/sessions",
        br#"{"filter":"upsample","width":64,"height":36}"#,
        "application/json",
    )
    .await;
    assert_eq!(st, 201, "{}", String::from_utf8_lossy(&body));
    let s: Value = serde_json::from_slice(&body).unwrap();
    let uid = s["id"].as_str().unwrap().to_string();
    let sparse = frames_shaded("fence", 3, 1, 2);
    let want = in_process("upsample", &sparse);
    for (i, f) in sparse.iter().enumerate() {
        let exr = write_exr_bytes(f, &opts).unwrap();
        let (st, _, body) = post_frame(addr, &uid, &exr).await;
        assert_eq!(st, 200, "{}", String::from_utf8_lossy(&body));
        same(
            &[exr_color(&body)],
            &[want[i].clone()],
            &format!("http sparse frame {i}"),
        );
    }
    let del = http(addr, "DELETE", &format!("/v1/sessions/{uid}"), b"", "text/plain").await;
    assert_eq!(del.0, 200);
    // A windowed filter: 202 while its window fills, then frame t after frame t + 2; the
    // flush gives the rest one per request, then 204.
    let (st, _, body) = http(
        addr,
        "POST",
        "/v1/sessions",
        br#"{"filter":"pixel_trace","params":{"window":4},"width":64,"height":36}"#,
        "application/json",
    )
    .await;
    assert_eq!(st, 201, "{}", String::from_utf8_lossy(&body));
    let s: Value = serde_json::from_slice(&body).unwrap();
    assert_eq!(s["lookahead"], 2);
    let pid = s["id"].as_str().unwrap().to_string();
    let mut f = create(
        "pixel_trace",
        &afterimage::pipeline::params::parse_assignments(&["window=4"]).unwrap(),
    )
    .unwrap();
    let want = run_sequence(f.as_mut(), &fr).unwrap();
    let mut got = Vec::new();
    for (i, f) in fr.iter().enumerate() {
        let exr = write_exr_bytes(f, &opts).unwrap();
        let (st, _, body) = post_frame(addr, &pid, &exr).await;
        if i < 2 {
            assert_eq!(st, 202, "{}", String::from_utf8_lossy(&body));
            let v: Value = serde_json::from_slice(&body).unwrap();
            assert!(v["message"].as_str().unwrap().contains("flush"), "{v}");
        } else {
            assert_eq!(st, 200, "{}", String::from_utf8_lossy(&body));
            got.push(exr_color(&body));
        }
    }
    for (headers, body) in flush_all(addr, &pid).await {
        assert!(
            headers.to_ascii_lowercase().contains("x-afterimage-ready: "),
            "{headers}"
        );
        got.push(exr_color(&body));
    }
    let want: Vec<Rgb> = want.into_iter().map(|o| o.color).collect();
    same(&got, &want, "http pixel_trace");
    assert_eq!(
        http(addr, "DELETE", &format!("/v1/sessions/{pid}"), b"", "text/plain")
            .await
            .0,
        200
    );
    // Errors: status and a JSON body naming the problem.
    let (st, _, body) = http(
        addr,
        "POST",
        "/v1/sessions",
        br#"{"filter":"taa","width":64,"height":36,"params":{"alpha":7}}"#,
        "application/json",
    )
    .await;
    assert_eq!(st, 400);
    assert!(String::from_utf8_lossy(&body).contains("alpha"));
    let (st, _, _) = http(addr, "POST", "/v1/sessions/nope/frames", b"x", "image/x-exr").await;
    assert_eq!(st, 404);
    let (st, _, body) = post_frame(addr, &id, b"not an exr").await;
    assert_eq!(st, 400, "{}", String::from_utf8_lossy(&body));
    let (st, _, body) = http(addr, "GET", "/v1/filters", b"", "text/plain").await;
    assert_eq!(st, 200);
    assert!(String::from_utf8_lossy(&body).contains("\"phlm\""));
    for p in ["/healthz", "/readyz"] {
        assert_eq!(http(addr, "GET", p, b"", "text/plain").await.0, 200, "{p}");
    }
    let (_, _, m) = http(addr, "GET", "/metrics", b"", "text/plain").await;
    let m = String::from_utf8_lossy(&m);
    assert!(
        m.contains("afterimage_sessions 1") && m.contains("afterimage_frames_total{filter=\"taa\"} 4"),
        "{m}"
    );
    assert!(
        m.contains("afterimage_stage_seconds_bucket{filter=\"taa\",stage=\"resolve\""),
        "{m}"
    );
    let (st, _, _) = http(addr, "DELETE", &format!("/v1/sessions/{id}"), b"", "text/plain").await;
    assert_eq!(st, 200);
    assert_eq!(
        http(addr, "GET", &format!("/v1/sessions/{id}"), b"", "text/plain")
            .await
            .0,
        404
    );
    r.shutdown().await.unwrap();
}

/// The EXR a reply carries, written to `path` for the pass-through check.
fn save(path: &std::path::Path, body: &[u8]) {
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    std::fs::write(path, body).unwrap();
}

/// The frame record a reply's EXR carries in `afterimage.record`.
fn exr_record(body: &[u8]) -> Value {
    use exr::prelude::*;
    let meta = exr::meta::MetaData::read_from_buffered(std::io::Cursor::new(body), false).unwrap();
    let record = meta
        .headers
        .iter()
        .find_map(
            |h| match h.own_attributes.other.get(&Text::from("afterimage.record")) {
                Some(AttributeValue::Text(t)) => Some(t.to_string()),
                _ => None,
            },
        )
        .expect("a record attribute");
    serde_json::from_str(&record).unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn replies_and_stream_outputs_replace_their_inputs() {
    use common::{assert_replaces, passthrough_inputs, Expect};
    let r = server(|_| {}).await;
    let addr = r.http_addr;
    let dir = tempfile::tempdir().unwrap();
    let variants = passthrough_inputs(&dir.path().join("in"));
    let new_session = |filter: &'static str| async move {
        let body = format!(r#"{{"filter":"{filter}","width":320,"height":180}}"#);
        let (st, _, body) = http(addr, "POST", "/v1/sessions", body.as_bytes(), "application/json").await;
        assert_eq!(st, 201, "{}", String::from_utf8_lossy(&body));
        let s: Value = serde_json::from_slice(&body).unwrap();
        s["id"].as_str().unwrap().to_string()
    };
    // HTTP: every layout, a causal and a windowed filter (whose output comes two frames
    // later, with the input it replaces kept in the session meanwhile).
    for (name, input) in &variants {
        for filter in ["taa", "pixel_trace"] {
            let id = new_session(filter).await;
            let mut replies = Vec::new();
            for n in 1..=3 {
                let file = std::fs::read(input.join(format!("frame_{n:04}.exr"))).unwrap();
                let (st, _, body) = post_frame(addr, &id, &file).await;
                assert!(
                    st == 200 || st == 202,
                    "{name} {filter}: {st} {}",
                    String::from_utf8_lossy(&body)
                );
                if st == 200 {
                    replies.push(body);
                }
            }
            replies.extend(flush_all(addr, &id).await.into_iter().map(|(_, body)| body));
            assert_eq!(replies.len(), 3, "{name} {filter}");
            for (k, body) in replies.iter().enumerate() {
                let n = k + 1;
                // Files without an index are numbered by the session in arrival order.
                assert_eq!(exr_record(body)["index"], k as u64, "{name} {filter}");
                let out = dir.path().join(format!("http/{name}-{filter}/frame_{n:04}.exr"));
                save(&out, body);
                assert_replaces(&input.join(format!("frame_{n:04}.exr")), &out, Expect::default());
            }
            http(addr, "DELETE", &format!("/v1/sessions/{id}"), b"", "text/plain").await;
        }
    }
    // gRPC: `afterimage stream` writes what `filter` writes.
    for (name, input) in &variants {
        let url = format!("http://{}", r.grpc_addr);
        let (input2, out) = (input.clone(), dir.path().join(format!("grpc/{name}")));
        let out2 = out.clone();
        let done = tokio::task::spawn_blocking(move || {
            common::bin()
                .args(["stream", "--server", &url, "--filter", "taa", "-i"])
                .arg(&input2)
                .arg("-o")
                .arg(&out2)
                .output()
                .unwrap()
        })
        .await
        .unwrap();
        assert!(
            done.status.success(),
            "{name}: {}",
            String::from_utf8_lossy(&done.stderr)
        );
        // Writing over the inputs is refused, as `filter` refuses it.
        if *name == "blender" {
            let (url, input3) = (format!("http://{}", r.grpc_addr), input.clone());
            let over = tokio::task::spawn_blocking(move || {
                common::bin()
                    .args(["stream", "--server", &url, "--filter", "taa", "-i"])
                    .arg(&input3)
                    .arg("-o")
                    .arg(&input3)
                    .output()
                    .unwrap()
            })
            .await
            .unwrap();
            let err = String::from_utf8_lossy(&over.stderr);
            assert!(!over.status.success() && err.contains("frame_0001.exr"), "{err}");
        }
        for n in 1..=3 {
            let name = format!("frame_{n:04}.exr");
            assert_replaces(&input.join(&name), &out.join(&name), Expect::default());
        }
    }
    r.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn http_frame_values_come_from_headers() {
    let r = server(|_| {}).await;
    let addr = r.http_addr;
    let (st, _, body) = http(
        addr,
        "POST",
        "/v1/sessions",
        br#"{"filter":"taa","width":64,"height":36}"#,
        "application/json",
    )
    .await;
    assert_eq!(st, 201);
    let id = serde_json::from_slice::<Value>(&body).unwrap()["id"]
        .as_str()
        .unwrap()
        .to_string();
    let fr = frames("fence", 3, 1);
    let post = |headers: String, body: Vec<u8>| {
        let id = id.clone();
        async move {
            http_with(
                addr,
                "POST",
                &format!("/v1/sessions/{id}/frames"),
                &headers,
                &body,
            )
            .await
        }
    };
    // Index and jitter from headers; the reply's record and attributes say so.
    let (st, _, body) = post(
        "x-afterimage-index: 1001\r\nx-afterimage-jitter: 0.25,-0.125\r\n".into(),
        plain_exr(&fr[0]),
    )
    .await;
    assert_eq!(st, 200, "{}", String::from_utf8_lossy(&body));
    assert_eq!(exr_record(&body)["index"], 1001);
    let f = afterimage::io::read_exr_frame_bytes(&body, std::path::Path::new("reply"), &Default::default())
        .unwrap();
    assert_eq!((f.meta.index, f.meta.jitter), (1001, [0.25, -0.125]));
    // Without one, the next index follows the last.
    let (_, _, body) = post(String::new(), plain_exr(&fr[1])).await;
    assert_eq!(exr_record(&body)["index"], 1002);
    // A reset from a header drops the history.
    let (_, _, body) = post("x-afterimage-reset: 1\r\n".into(), plain_exr(&fr[2])).await;
    assert_eq!(exr_record(&body)["pixels"]["history_reset"], 64 * 36);
    // Bad values are refused, naming the header.
    for (h, want) in [
        ("x-afterimage-index: -3", "x-afterimage-index"),
        ("x-afterimage-reset: maybe", "x-afterimage-reset"),
        ("x-afterimage-jitter: 0.5", "x-afterimage-jitter"),
        ("x-afterimage-jitter: 7,0", "-1..=1"),
    ] {
        let (st, _, body) = post(format!("{h}\r\n"), plain_exr(&fr[0])).await;
        let text = String::from_utf8_lossy(&body);
        assert!(st == 400 && text.contains(want), "{h}: {st} {text}");
    }
    // Output options from the query string.
    let (st, _, body) = http(
        addr,
        "POST",
        &format!("/v1/sessions/{id}/frames?keep=none&precision=half&compression=piz"),
        &plain_exr(&fr[0]),
        "image/x-exr",
    )
    .await;
    assert_eq!(st, 200, "{}", String::from_utf8_lossy(&body));
    let meta = exr::meta::MetaData::read_from_buffered(std::io::Cursor::new(&body[..]), false).unwrap();
    let h = &meta.headers[0];
    assert_eq!(h.compression, exr::compression::Compression::PIZ);
    let names: Vec<String> = h.channels.list.iter().map(|c| c.name.to_string()).collect();
    assert_eq!(names, ["B", "G", "R"]);
    assert_eq!(
        h.channels.list[0].sample_type,
        exr::meta::attribute::SampleType::F16
    );
    // A windowed filter's inputs kept with ?keep=none are written that way by a later
    // request that asks for more (the flush, with the default keep=all).
    let (_, _, body) = http(
        addr,
        "POST",
        "/v1/sessions",
        br#"{"filter":"pixel_trace","params":{"window":4},"width":64,"height":36}"#,
        "application/json",
    )
    .await;
    let pid = serde_json::from_slice::<Value>(&body).unwrap()["id"]
        .as_str()
        .unwrap()
        .to_string();
    let full = WriteOptions {
        precision: Precision::F32,
        compression: Compression::Zip,
    };
    let mut replies = Vec::new();
    for f in &fr {
        let exr = write_exr_bytes(f, &full).unwrap();
        let (st, _, body) = http(
            addr,
            "POST",
            &format!("/v1/sessions/{pid}/frames?keep=none"),
            &exr,
            "image/x-exr",
        )
        .await;
        assert!(st == 200 || st == 202, "{st} {}", String::from_utf8_lossy(&body));
        if st == 200 {
            replies.push(body);
        }
    }
    replies.extend(flush_all(addr, &pid).await.into_iter().map(|(_, body)| body));
    assert_eq!(replies.len(), 3);
    for body in &replies {
        let meta = exr::meta::MetaData::read_from_buffered(std::io::Cursor::new(&body[..]), false).unwrap();
        let names: Vec<String> = meta.headers[0]
            .channels
            .list
            .iter()
            .map(|c| c.name.to_string())
            .collect();
        assert_eq!(names, ["B", "G", "R"]);
    }
    let (st, _, body) = http(
        addr,
        "POST",
        &format!("/v1/sessions/{id}/frames?keep=most"),
        &plain_exr(&fr[0]),
        "image/x-exr",
    )
    .await;
    assert!(
        st == 400 && String::from_utf8_lossy(&body).contains("filtered"),
        "{st}"
    );
    r.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_stream_command_filters_a_scene_remotely() {
    let r = server(|_| {}).await;
    let url = format!("http://{}", r.grpc_addr);
    for transport in ["grpc", "shm"] {
        let dir = tempfile::tempdir().unwrap();
        let out_dir = dir.path().to_path_buf();
        let url = url.clone();
        let out = tokio::task::spawn_blocking(move || {
            std::process::Command::new(env!("CARGO_BIN_EXE_afterimage"))
                .args([
                    "stream", "--server", &url, "--filter", "taa", "--scene", "fence", "--size", "64x36",
                ])
                .args([
                    "--frames",
                    "3",
                    "--spp",
                    "4",
                    "--reference",
                    "--compare",
                    "--transport",
                    transport,
                    "--output",
                ])
                .arg(&out_dir)
                .output()
                .unwrap()
        })
        .await
        .unwrap();
        let stdout = String::from_utf8_lossy(&out.stdout);
        assert!(
            out.status.success(),
            "{transport}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        assert!(
            stdout.contains("3 frames of 64x36")
                && stdout.contains("mean PSNR")
                && stdout.contains("in process")
                && stdout.contains("median to median")
                && stdout.contains("mean to mean")
                && stdout.contains("before the stream")
                && stdout.contains("copy floor:")
                && stdout.contains("client CPU:")
                && stdout.contains("cores busy while filtering"),
            "{transport}: {stdout}"
        );
        // What it wrote is what filtering in process gives.
        let want = in_process("taa", &frames("fence", 3, 1));
        for (i, w) in want.iter().enumerate() {
            let f = afterimage::io::read_frame(
                &dir.path().join(format!("frame_{i:04}.exr")),
                &Default::default(),
            )
            .unwrap();
            same(
                &[f.color().clone()],
                std::slice::from_ref(w),
                &format!("{transport} output"),
            );
        }
        // It closed its session.
        assert_eq!(r.service.sessions.totals().sessions, 0);
    }
    r.shutdown().await.unwrap();
}

// ---------------------------------------------------------------------------------------
// Hostile clients. Each test ends by checking that the server still answers `/healthz`
// and that a fresh session still filters bit-identically.

/// The server is alive: `/healthz` answers and a new gRPC session filters three frames
/// exactly as in process.
async fn still_serving(r: &Running) {
    let (st, _, _) = tokio::time::timeout(
        std::time::Duration::from_secs(10),
        http(r.http_addr, "GET", "/healthz", b"", "text/plain"),
    )
    .await
    .expect("/healthz answers within 10 s");
    assert_eq!(st, 200);
    let mut c = client(r).await;
    let s = open(&mut c, "taa").await;
    let fr = frames("fence", 3, 7);
    let got = stream_all(&mut c, &s, &fr, F32).await.unwrap();
    same(&got, &in_process("taa", &fr), "a fresh session after the attack");
}

/// Opens an HTTP session and returns its id.
async fn http_session(addr: std::net::SocketAddr, body: &str) -> String {
    let (st, _, b) = http(addr, "POST", "/v1/sessions", body.as_bytes(), "application/json").await;
    assert_eq!(st, 201, "{}", String::from_utf8_lossy(&b));
    let v: Value = serde_json::from_slice(&b).unwrap();
    v["id"].as_str().unwrap().to_string()
}

/// Sends only a request head (no body) and reads the reply that comes before the body:
/// status, headers and body; None when the server does not answer within `secs`.
async fn head_only(addr: std::net::SocketAddr, head: &str, secs: u64) -> Option<(u16, String)> {
    let mut s = tokio::net::TcpStream::connect(addr).await.unwrap();
    s.write_all(head.as_bytes()).await.unwrap();
    let mut buf = Vec::new();
    let read = async {
        let mut chunk = [0u8; 4096];
        loop {
            match s.read(&mut chunk).await {
                Ok(0) | Err(_) => break,
                Ok(n) => buf.extend_from_slice(&chunk[..n]),
            }
            if let Some(split) = buf.windows(4).position(|w| w == b"\r\n\r\n") {
                let text = String::from_utf8_lossy(&buf).to_string();
                let len = text[..split]
                    .lines()
                    .find_map(|l| {
                        l.to_ascii_lowercase()
                            .strip_prefix("content-length:")
                            .map(|v| v.trim().parse::<usize>().unwrap_or(0))
                    })
                    .unwrap_or(0);
                if buf.len() >= split + 4 + len {
                    break;
                }
            }
        }
    };
    tokio::time::timeout(std::time::Duration::from_secs(secs), read)
        .await
        .ok()?;
    let text = String::from_utf8_lossy(&buf).to_string();
    Some((text.get(9..12)?.parse().ok()?, text))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_exr_header_declaring_a_huge_image_is_refused_before_allocation() {
    let r = server(|_| {}).await;
    let id = http_session(r.http_addr, r#"{"filter":"taa","width":64,"height":36}"#).await;
    let exr = common::lying_exr(100_000, 100_000);
    assert!(exr.len() < 1000, "{} bytes", exr.len());
    let (st, _, body) = http(
        r.http_addr,
        "POST",
        &format!("/v1/sessions/{id}/frames"),
        &exr,
        "image/x-exr",
    )
    .await;
    let body = String::from_utf8_lossy(&body);
    assert_eq!(st, 400, "{body}");
    assert!(body.contains("100000x100000") && body.contains("64x36"), "{body}");
    still_serving(&r).await;
    r.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn grpc_byte_lengths_that_overflow_are_refused() {
    let r = server(|_| {}).await;
    let mut c = client(&r).await;
    let s = open(&mut c, "taa").await;
    let ch = |name: &str, len: u64| pb::ChannelHeader {
        name: name.into(),
        sample: pb::SampleType::F32 as i32,
        compression: pb::Compression::None as i32,
        byte_length: len,
    };
    // 2^63 + (2^63 + 16) wraps to 16 in u64 arithmetic.
    let h = pb::FrameHeader {
        session_id: s.id.clone(),
        channels: vec![ch("color", 1 << 63), ch("depth", (1 << 63) + 16)],
        ..Default::default()
    };
    let e = raw_stream(
        &mut c,
        vec![
            frame_chunk::Part::Header(h),
            frame_chunk::Part::Data(pb::DataChunk {
                data: vec![0; 16].into(),
            }),
        ],
    )
    .await;
    assert_eq!(e.code(), Code::InvalidArgument, "{}", e.message());
    assert!(e.message().contains("color"), "{}", e.message());
    still_serving(&r).await;
    r.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn concurrent_frames_to_one_session_are_refused_not_deadlocked() {
    let r = server(|_| {}).await;
    let addr = r.http_addr;
    let id = http_session(addr, r#"{"filter":"phlm","width":64,"height":36}"#).await;
    let opts = WriteOptions {
        precision: Precision::F32,
        compression: Compression::Zip,
    };
    let exr = write_exr_bytes(&frames("fence", 1, 1)[0], &opts).unwrap();
    let mut tasks = Vec::new();
    for _ in 0..8 {
        let (exr, id) = (exr.clone(), id.clone());
        tasks.push(tokio::spawn(async move {
            let mut codes = Vec::new();
            for _ in 0..6 {
                let (st, _, body) = post_frame(addr, &id, &exr).await;
                if st == 409 {
                    let b = String::from_utf8_lossy(&body);
                    assert!(b.contains("session busy: "), "{b}");
                }
                codes.push(st);
            }
            codes
        }));
    }
    let all = tokio::time::timeout(std::time::Duration::from_secs(120), async {
        let mut codes = Vec::new();
        for t in tasks {
            codes.extend(t.await.unwrap());
        }
        codes
    })
    .await
    .expect("48 concurrent frames to one session finish within 120 s (no deadlock)");
    assert!(all.iter().all(|&c| c == 200 || c == 409), "{all:?}");
    let ok = all.iter().filter(|&&c| c == 200).count() as u64;
    assert!(ok >= 1, "{all:?}");
    // Every accepted frame went through the filter once; GET never waits for a frame.
    let (st, _, body) = http(addr, "GET", &format!("/v1/sessions/{id}"), b"", "text/plain").await;
    assert_eq!(st, 200);
    let v: Value = serde_json::from_slice(&body).unwrap();
    assert_eq!(v["frames"].as_u64(), Some(ok), "{v}");

    // Two gRPC streams on one session: the second is refused, the first is unharmed.
    let mut c = client(&r).await;
    let s = open(&mut c, "taa").await;
    let fr = frames("flyover", 8, 3);
    let (tx, rx) = tokio::sync::mpsc::channel::<pb::FrameChunk>(64);
    let mut first = c
        .inner
        .stream(tokio_stream::wrappers::ReceiverStream::new(rx))
        .await
        .unwrap()
        .into_inner();
    for p in frame_parts(&fr[0], &s.id, &[afterimage::frame::ChannelKind::Color]) {
        tx.send(pb::FrameChunk { part: Some(p) }).await.unwrap();
    }
    let head = first.message().await.unwrap().unwrap();
    assert!(matches!(head.part, Some(pb::filtered_chunk::Part::Header(_))));
    let mut c2 = client(&r).await;
    let e = tokio::time::timeout(
        std::time::Duration::from_secs(30),
        raw_stream(
            &mut c2,
            frame_parts(&fr[1], &s.id, &[afterimage::frame::ChannelKind::Color]),
        ),
    )
    .await
    .expect("a second stream on a streamed session is answered at once");
    assert_eq!(e.code(), Code::FailedPrecondition, "{}", e.message());
    assert!(e.message().contains("another stream"), "{}", e.message());
    drop(tx);
    drop(first);
    still_serving(&r).await;
    r.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bodies_and_frames_larger_than_the_session_are_refused_before_reading() {
    let r = server(|_| {}).await;
    let addr = r.http_addr;
    // An unknown session: 404 before a byte of the 1 GiB body is sent.
    let head = "POST /v1/sessions/0123/frames HTTP/1.1\r\nHost: x\r\nContent-Type: image/x-exr\r\nContent-Length: 1073741824\r\n\r\n";
    let (st, text) = head_only(addr, head, 10)
        .await
        .expect("an answer without the body");
    assert_eq!(st, 404, "{text}");
    // A known 64x36 session: a body far larger than any EXR of that size gets 413.
    let id = http_session(addr, r#"{"filter":"taa","width":64,"height":36}"#).await;
    let head = format!("POST /v1/sessions/{id}/frames HTTP/1.1\r\nHost: x\r\nContent-Type: image/x-exr\r\nContent-Length: 536870912\r\n\r\n");
    let (st, text) = head_only(addr, &head, 10)
        .await
        .expect("an answer without the body");
    assert_eq!(st, 413, "{text}");
    assert!(text.contains("536870912") && text.contains("64x36"), "{text}");
    // A ZIP-compressed EXR that declares 16384x8192 (1.6 MB of zeros that would decode to
    // 3.2 GB) is refused from its header.
    let big = {
        let f = Frame::new([0, 1, 2].map(|_| Plane::filled(16384, 8192, 0.0f32))).unwrap();
        let opts = WriteOptions {
            precision: Precision::F16,
            compression: Compression::Zip,
        };
        write_exr_bytes(&f, &opts).unwrap()
    };
    let (st, _, body) = post_frame(addr, &id, &big).await;
    let body = String::from_utf8_lossy(&body);
    assert_eq!(st, 400, "{body}");
    assert!(
        body.contains("16384x8192") && body.contains("before decoding"),
        "{body}"
    );
    // gRPC: a header announcing more bytes than the session's frame can hold is refused
    // before any data.
    let mut c = client(&r).await;
    let s = open(&mut c, "taa").await;
    let h = pb::FrameHeader {
        session_id: s.id.clone(),
        channels: vec![pb::ChannelHeader {
            name: "color".into(),
            sample: pb::SampleType::F32 as i32,
            compression: pb::Compression::None as i32,
            byte_length: 900 << 20,
        }],
        ..Default::default()
    };
    let e = tokio::time::timeout(
        std::time::Duration::from_secs(10),
        raw_stream(&mut c, vec![frame_chunk::Part::Header(h)]),
    )
    .await
    .expect("refused at the header");
    assert_eq!(e.code(), Code::InvalidArgument, "{}", e.message());
    assert!(e.message().contains("27648"), "{}", e.message());
    still_serving(&r).await;
    r.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_budget_counts_the_state_the_parameters_build() {
    // pixel_trace holds (window + 1) frames of 36 B/px: at 64x36, 1.4 MB with the default
    // window of 16 and 21 MB with 256. An 8 MiB budget takes the first, not the second.
    let r = server(|c| c.memory_budget_mib = 8).await;
    let mut c = client(&r).await;
    open(&mut c, "pixel_trace").await;
    let mut req = session_req("pixel_trace");
    req.params.insert("window".into(), "256".into());
    let e = c.inner.create_session(req).await.unwrap_err();
    assert_eq!(e.code(), Code::ResourceExhausted, "{}", e.message());
    assert!(e.message().contains("pixel_trace"), "{}", e.message());
    still_serving(&r).await;
    r.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_oversize_chunk_is_an_error_not_a_silent_end() {
    let r = server(|_| {}).await;
    let mut c = client(&r).await;
    let s = open(&mut c, "taa").await;
    let fr = frames("fence", 1, 1);
    let mut parts = frame_parts(&fr[0], &s.id, &[afterimage::frame::ChannelKind::Color]);
    parts.truncate(1);
    parts.push(frame_chunk::Part::Data(pb::DataChunk {
        data: vec![0u8; 5 << 20].into(),
    }));
    let e = raw_stream(&mut c, parts).await;
    assert_ne!(e.code(), Code::Ok, "{}", e.message());
    assert!(e.message().contains("chunk"), "{}", e.message());
    let m = r.service.metrics.render(r.service.sessions.totals());
    assert!(
        m.contains("afterimage_errors_total{reason=\"too_large\"} 1"),
        "{m}"
    );
    still_serving(&r).await;
    r.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn error_messages_do_not_echo_long_input() {
    let r = server(|_| {}).await;
    let name = "x".repeat(60_000);
    let body = format!(r#"{{"filter":"{name}","width":64,"height":36}}"#);
    let (st, _, b) = http(
        r.http_addr,
        "POST",
        "/v1/sessions",
        body.as_bytes(),
        "application/json",
    )
    .await;
    assert_eq!(st, 400);
    assert!(b.len() < 2048, "{} bytes of error", b.len());
    assert!(String::from_utf8_lossy(&b).contains("xxxxxxxx"));
    let mut c = client(&r).await;
    let e = c
        .inner
        .create_session(session_req(&"y".repeat(1 << 20)))
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::InvalidArgument);
    assert!(e.message().len() < 2048, "{} bytes of error", e.message().len());
    still_serving(&r).await;
    r.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn slow_and_silent_connections_are_closed_and_capped() {
    let r = server(|c| {
        c.header_timeout_s = 1;
        c.max_connections = 210;
    })
    .await;
    // 200 connections that send half a request head and stop; one to the gRPC port that
    // sends nothing.
    let mut slow = Vec::new();
    for _ in 0..200 {
        let mut s = tokio::net::TcpStream::connect(r.http_addr).await.unwrap();
        s.write_all(b"GET /healthz HTTP/1.1\r\nHost: x\r\n")
            .await
            .unwrap();
        slow.push(s);
    }
    slow.push(tokio::net::TcpStream::connect(r.grpc_addr).await.unwrap());
    // Every one of them is closed by the server within a few seconds.
    let closed = tokio::time::timeout(std::time::Duration::from_secs(10), async {
        for mut s in slow {
            let mut buf = [0u8; 1024];
            loop {
                match s.read(&mut buf).await {
                    Ok(0) | Err(_) => break,
                    Ok(_) => continue,
                }
            }
        }
    })
    .await;
    assert!(
        closed.is_ok(),
        "slow-header connections were still open after 10 s"
    );
    still_serving(&r).await;
    r.shutdown().await.unwrap();

    // Past max_connections, a connection is closed at once; the ones holding the slots
    // time out and the server answers again.
    let r = server(|c| {
        c.header_timeout_s = 2;
        c.max_connections = 3;
    })
    .await;
    let mut held = Vec::new();
    for _ in 0..3 {
        held.push(tokio::net::TcpStream::connect(r.http_addr).await.unwrap());
    }
    tokio::time::sleep(std::time::Duration::from_millis(200)).await;
    let mut extra = tokio::net::TcpStream::connect(r.http_addr).await.unwrap();
    let mut buf = [0u8; 16];
    let n = tokio::time::timeout(std::time::Duration::from_secs(1), extra.read(&mut buf))
        .await
        .expect("the fourth connection is closed at once");
    assert!(matches!(n, Ok(0) | Err(_)), "{n:?}");
    let m = r.service.metrics.render(r.service.sessions.totals());
    assert!(
        m.contains("afterimage_errors_total{reason=\"too_many_connections\"}"),
        "{m}"
    );
    tokio::time::sleep(std::time::Duration::from_millis(2500)).await;
    drop(held);
    still_serving(&r).await;
    r.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn shutdown_drains_readyz_503_while_a_frame_finishes() {
    use afterimage::report::synthetic_frame;
    let r = server(|c| c.shutdown_deadline_s = 60).await;
    let addr = r.http_addr;
    // A pixel_trace flush of a 33-frame window: seconds of work in one request.
    let (w, h) = (160, 96);
    let id = http_session(
        addr,
        &format!(r#"{{"filter":"pixel_trace","params":{{"window":32}},"width":{w},"height":{h}}}"#),
    )
    .await;
    let opts = WriteOptions {
        precision: Precision::F16,
        compression: Compression::Zip,
    };
    for i in 0..16 {
        let exr = write_exr_bytes(&synthetic_frame(w, h, i), &opts).unwrap();
        let (st, _, b) = post_frame(addr, &id, &exr).await;
        assert_eq!(st, 202, "{}", String::from_utf8_lossy(&b));
    }
    let flush = tokio::spawn(async move {
        let t = std::time::Instant::now();
        let (st, _, _) = http(
            addr,
            "POST",
            &format!("/v1/sessions/{id}/flush"),
            b"",
            "text/plain",
        )
        .await;
        (st, t.elapsed())
    });
    // Wait until the flush is being filtered, then ask the server to stop.
    let t = std::time::Instant::now();
    while r.service.in_flight() == 0 {
        assert!(t.elapsed().as_secs() < 10, "the flush never started");
        tokio::time::sleep(std::time::Duration::from_millis(5)).await;
    }
    r.begin_shutdown();
    let mut saw_503 = false;
    while !flush.is_finished() {
        let (st, _, _) = http(addr, "GET", "/readyz", b"", "text/plain").await;
        if st == 503 {
            saw_503 = true;
            // New work is refused while draining.
            let (st, _, b) = http(
                addr,
                "POST",
                "/v1/sessions",
                br#"{"filter":"taa","width":8,"height":8}"#,
                "application/json",
            )
            .await;
            assert_eq!(st, 503, "{}", String::from_utf8_lossy(&b));
            break;
        }
        tokio::time::sleep(std::time::Duration::from_millis(5)).await;
    }
    assert!(
        saw_503,
        "/readyz never answered 503 while the flush was in flight"
    );
    let (st, took) = flush.await.unwrap();
    assert_eq!(st, 200, "the frame in flight finished with its output");
    eprintln!("flush took {took:?}");
    r.stopped().await.unwrap();
    assert!(
        tokio::net::TcpStream::connect(addr).await.is_err(),
        "the HTTP listener is closed after the drain"
    );
}

/// Two keys: `a` (at most 2 sessions) from a keys file of hashes, `b` plain.
async fn keyed_server(tweak: impl FnOnce(&mut Config)) -> (Running, tempfile::TempDir) {
    let dir = tempfile::tempdir().unwrap();
    let keys = dir.path().join("keys.toml");
    std::fs::write(
        &keys,
        format!(
            "[[key]]\nname = \"a\"\nsha256 = \"{}\"\nmax_sessions = 2\n",
            afterimage::session::access::hash_hex(KEY_A)
        ),
    )
    .unwrap();
    let r = server(|c| {
        c.api_keys_file = keys.display().to_string();
        c.api_keys_plain = Some(format!("b:{KEY_B}"));
        tweak(c);
    })
    .await;
    (r, dir)
}

/// An EXR of `f`'s colour alone as `R,G,B`, no attributes at all (as a renderer without
/// our attributes writes it).
fn plain_exr(f: &Frame) -> Vec<u8> {
    use exr::prelude::*;
    let list = f
        .color()
        .iter()
        .zip(["R", "G", "B"])
        .map(|(p, n)| AnyChannel::new(n, FlatSamples::F32(p.data().to_vec())))
        .collect();
    let image = Image::from_channels((f.width(), f.height()), AnyChannels::sort(list));
    let mut out = std::io::Cursor::new(Vec::new());
    image.write().to_buffered(&mut out).unwrap();
    out.into_inner()
}

const STATE_TYPE: &str = "application/vnd.afterimage.state";
const KEY_A: &str = "key-a-0123456789abcdef";
const KEY_B: &str = "key-b-0123456789abcdef";

async fn keyed_client(r: &Running, key: Option<&str>) -> Client {
    let opts = afterimage::server::client::ConnectOptions {
        api_key: key.map(str::to_string),
        ..Default::default()
    };
    Client::connect_with(format!("http://{}", r.grpc_addr), &opts)
        .await
        .unwrap()
}

/// An HTTP/1.1 exchange with extra request headers.
async fn http_with(
    addr: std::net::SocketAddr,
    method: &str,
    path: &str,
    headers: &str,
    body: &[u8],
) -> (u16, String, Vec<u8>) {
    let mut s = tokio::net::TcpStream::connect(addr).await.unwrap();
    let head = format!(
        "{method} {path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\n{headers}Content-Length: {}\r\n\r\n",
        body.len()
    );
    s.write_all(head.as_bytes()).await.unwrap();
    s.write_all(body).await.unwrap();
    let mut buf = Vec::new();
    s.read_to_end(&mut buf).await.unwrap();
    let split = buf.windows(4).position(|w| w == b"\r\n\r\n").unwrap();
    let text = String::from_utf8_lossy(&buf[..split]).to_string();
    (text[9..12].parse().unwrap(), text, buf[split + 4..].to_vec())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn api_keys_own_their_sessions_and_quotas() {
    let (r, _dir) = keyed_server(|_| {}).await;
    // gRPC: no key, a wrong key.
    for key in [None, Some("not-a-key-0123456789")] {
        let mut c = keyed_client(&r, key).await;
        let e = c.inner.create_session(session_req("taa")).await.unwrap_err();
        assert_eq!(e.code(), Code::Unauthenticated, "{key:?}: {}", e.message());
        let e = c.inner.list_filters(pb::ListFiltersRequest {}).await.unwrap_err();
        assert_eq!(e.code(), Code::Unauthenticated);
    }
    let mut a = keyed_client(&r, Some(KEY_A)).await;
    let mut b = keyed_client(&r, Some(KEY_B)).await;
    let sa = open(&mut a, "taa").await;
    // Another key's session is not found, whatever the call.
    let e = b
        .inner
        .get_session(pb::GetSessionRequest { id: sa.id.clone() })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::NotFound, "{}", e.message());
    let fr = frames("fence", 2, 1);
    let e = stream_all(&mut b, &sa, &fr, F32).await.unwrap_err();
    assert_eq!(e.code(), Code::NotFound, "{}", e.message());
    let e = b
        .inner
        .close_session(pb::CloseSessionRequest { id: sa.id.clone() })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::NotFound);
    // Its owner streams it as usual.
    let got = stream_all(&mut a, &sa, &fr, F32).await.unwrap();
    same(&got, &in_process("taa", &fr), "keyed session");
    // Key a's quota is two sessions; key b is not affected.
    open(&mut a, "taa").await;
    let e = a.inner.create_session(session_req("taa")).await.unwrap_err();
    assert_eq!(e.code(), Code::ResourceExhausted, "{}", e.message());
    assert!(
        e.message().contains("key a has 2 sessions open"),
        "{}",
        e.message()
    );
    open(&mut b, "taa").await;

    // HTTP: 401 with WWW-Authenticate without a key or with a wrong one; another key's
    // session is 404; health and readiness stay open, and so do metrics by default.
    let addr = r.http_addr;
    let body = br#"{"filter":"taa","width":64,"height":36}"#;
    for auth in [
        "",
        "Authorization: Bearer nope-nope-nope-nope\r\n",
        "Authorization: Basic abc\r\n",
    ] {
        let (st, head, _) = http_with(
            addr,
            "POST",
            "/v1/sessions",
            &format!("{auth}Content-Type: application/json\r\n"),
            body,
        )
        .await;
        assert_eq!(st, 401, "{auth:?}");
        assert!(
            head.to_ascii_lowercase().contains("www-authenticate: bearer"),
            "{head}"
        );
    }
    let auth_b = format!("Authorization: Bearer {KEY_B}\r\n");
    let (st, _, _) = http_with(addr, "GET", &format!("/v1/sessions/{}", sa.id), &auth_b, b"").await;
    assert_eq!(st, 404);
    let (st, _, _) = http_with(addr, "DELETE", &format!("/v1/sessions/{}", sa.id), &auth_b, b"").await;
    assert_eq!(st, 404);
    let auth_a = format!("Authorization: Bearer {KEY_A}\r\n");
    let (st, _, b2) = http_with(addr, "GET", &format!("/v1/sessions/{}", sa.id), &auth_a, b"").await;
    assert_eq!(st, 200, "{}", String::from_utf8_lossy(&b2));
    for p in ["/healthz", "/readyz", "/metrics"] {
        assert_eq!(http(addr, "GET", p, b"", "text/plain").await.0, 200, "{p}");
    }
    r.shutdown().await.unwrap();
    // Metrics can be keyed too.
    let (r, _dir) = keyed_server(|c| c.metrics_require_key = true).await;
    assert_eq!(
        http(r.http_addr, "GET", "/metrics", b"", "text/plain").await.0,
        401
    );
    let (st, _, _) = http_with(
        r.http_addr,
        "GET",
        "/metrics",
        &format!("Authorization: Bearer {KEY_B}\r\n"),
        b"",
    )
    .await;
    assert_eq!(st, 200);
    r.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_public_address_needs_keys() {
    let public = |c: &mut Config| c.http_addr = "0.0.0.0:0".into();
    let mut c = Config {
        grpc_addr: "127.0.0.1:0".into(),
        ..Config::default()
    };
    public(&mut c);
    let e = start(c.clone()).await.err().expect("refused").to_string();
    assert!(
        e.contains("0.0.0.0:0") && e.contains("without API keys") && e.contains("allow_unauthenticated"),
        "{e}"
    );
    let ok = start(Config {
        allow_unauthenticated: true,
        ..c.clone()
    })
    .await
    .unwrap();
    ok.shutdown().await.unwrap();
    let ok = start(Config {
        api_keys_plain: Some(format!("b:{KEY_B}")),
        ..c
    })
    .await
    .unwrap();
    ok.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tls_end_to_end_over_grpc_and_http() {
    use tokio_rustls::rustls;
    let dir = tempfile::tempdir().unwrap();
    let ck = rcgen::generate_simple_self_signed(vec!["localhost".to_string()]).unwrap();
    let (cert, key) = (dir.path().join("cert.pem"), dir.path().join("key.pem"));
    std::fs::write(&cert, ck.cert.pem()).unwrap();
    std::fs::write(&key, ck.signing_key.serialize_pem()).unwrap();
    let r = server(|c| {
        c.tls_cert = cert.display().to_string();
        c.tls_key = key.display().to_string();
        c.api_keys_plain = Some(format!("b:{KEY_B}"));
    })
    .await;
    // gRPC over TLS, with a key: bit-identical to in-process filtering.
    let opts = afterimage::server::client::ConnectOptions {
        api_key: Some(KEY_B.into()),
        tls_ca: Some(ck.cert.pem().into_bytes()),
        tls_domain: Some("localhost".into()),
        route: None,
    };
    let mut c = Client::connect_with(format!("https://localhost:{}", r.grpc_addr.port()), &opts)
        .await
        .unwrap();
    let s = open(&mut c, "taa").await;
    let fr = frames("fence", 3, 2);
    same(
        &stream_all(&mut c, &s, &fr, F32).await.unwrap(),
        &in_process("taa", &fr),
        "gRPC over TLS",
    );
    // Without the CA the client refuses to connect.
    let e = Client::connect_with(
        format!("https://localhost:{}", r.grpc_addr.port()),
        &afterimage::server::client::ConnectOptions::default(),
    )
    .await
    .err()
    .unwrap();
    assert!(e.to_string().contains("CA"), "{e}");
    // HTTP over TLS.
    let mut roots = rustls::RootCertStore::empty();
    roots.add(ck.cert.der().clone()).unwrap();
    let config = rustls::ClientConfig::builder_with_provider(std::sync::Arc::new(
        rustls::crypto::ring::default_provider(),
    ))
    .with_safe_default_protocol_versions()
    .unwrap()
    .with_root_certificates(roots)
    .with_no_client_auth();
    let connector = tokio_rustls::TlsConnector::from(std::sync::Arc::new(config));
    let tcp = tokio::net::TcpStream::connect(r.http_addr).await.unwrap();
    let mut tls = connector
        .connect(rustls::pki_types::ServerName::try_from("localhost").unwrap(), tcp)
        .await
        .unwrap();
    tls.write_all(format!("GET /v1/sessions/{} HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\nAuthorization: Bearer {KEY_B}\r\n\r\n", s.id).as_bytes())
        .await
        .unwrap();
    let mut buf = Vec::new();
    let _ = tls.read_to_end(&mut buf).await;
    let text = String::from_utf8_lossy(&buf);
    assert!(text.starts_with("HTTP/1.1 200"), "{text}");
    assert!(text.contains("\"frames\":3"), "{text}");
    // Plain HTTP to the TLS port gets no answer but a closed connection, and the server
    // goes on.
    let (st, _) = head_only(r.http_addr, "GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n", 5)
        .await
        .unwrap_or((0, String::new()));
    assert_ne!(st, 200);
    r.shutdown().await.unwrap();
}

/// A port free now on loopback.
fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// Resident memory of process `pid`, MiB.
fn rss_mib(pid: u32) -> f64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap_or_default();
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<f64>().ok())
        .map_or(0.0, |kb| kb / 1024.0)
}

/// What one misbehaving client does, in turn: garbage EXR bodies, bodies larger than
/// the session allows, slow headers, gRPC headers that lie about lengths, huge filter
/// names, and frames for the good clients' sessions (refused: they are streamed).
async fn misbehave(
    http_addr: std::net::SocketAddr,
    grpc_url: String,
    victims: Vec<String>,
    until: std::time::Instant,
) -> u64 {
    let mut c = Client::connect(grpc_url).await.unwrap();
    let own = open(&mut c, "taa").await;
    let mut n = 0u64;
    while std::time::Instant::now() < until {
        n += 1;
        match n % 6 {
            0 => {
                let (st, _, _) = http(
                    http_addr,
                    "POST",
                    &format!("/v1/sessions/{}/frames", own.id),
                    &vec![0x76u8; 5000],
                    "image/x-exr",
                )
                .await;
                assert_eq!(st, 400);
            }
            1 => {
                let head = format!(
                    "POST /v1/sessions/{}/frames HTTP/1.1\r\nHost: x\r\nContent-Length: 900000000\r\n\r\n",
                    own.id
                );
                let r = head_only(http_addr, &head, 5).await;
                assert_eq!(r.map(|r| r.0), Some(413));
            }
            2 => {
                let mut s = tokio::net::TcpStream::connect(http_addr).await.unwrap();
                s.write_all(b"GET /healthz HTTP/1.1\r\nHo").await.unwrap();
                tokio::time::sleep(std::time::Duration::from_millis(300)).await;
            }
            3 => {
                let h = pb::FrameHeader {
                    session_id: own.id.clone(),
                    channels: vec![pb::ChannelHeader {
                        name: "color".into(),
                        sample: 0,
                        compression: 0,
                        byte_length: u64::MAX,
                    }],
                    ..Default::default()
                };
                let e = raw_stream(&mut c, vec![frame_chunk::Part::Header(h)]).await;
                assert_eq!(e.code(), Code::InvalidArgument);
            }
            4 => {
                let e = c
                    .inner
                    .create_session(session_req(&"z".repeat(100_000)))
                    .await
                    .unwrap_err();
                assert_eq!(e.code(), Code::InvalidArgument);
            }
            _ => {
                let victim = &victims[(n as usize / 6) % victims.len()];
                let fr = frames("fence", 1, 1);
                let e = raw_stream(
                    &mut c,
                    frame_parts(&fr[0], victim, &[afterimage::frame::ChannelKind::Color]),
                )
                .await;
                assert_eq!(e.code(), Code::FailedPrecondition, "{}", e.message());
            }
        }
    }
    n
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
#[ignore = "a load and soak run: AFTERIMAGE_SOAK_SECS=60 cargo test --release --test server soak -- --ignored --nocapture"]
async fn soak_eight_clients_and_one_misbehaving() {
    use afterimage::scene::{Jitter, Scene, Settings};
    let secs: u64 = std::env::var("AFTERIMAGE_SOAK_SECS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(60);
    let (gp, hp) = (free_port(), free_port());
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_afterimage"))
        .arg("serve")
        .env("AFTERIMAGE_GRPC_ADDR", format!("127.0.0.1:{gp}"))
        .env("AFTERIMAGE_HTTP_ADDR", format!("127.0.0.1:{hp}"))
        .env("AFTERIMAGE_HEADER_TIMEOUT_S", "2")
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let pid = child.id();
    let http_addr: std::net::SocketAddr = format!("127.0.0.1:{hp}").parse().unwrap();
    let grpc_url = format!("http://127.0.0.1:{gp}");
    for _ in 0..100 {
        if tokio::net::TcpStream::connect(http_addr).await.is_ok() {
            break;
        }
        tokio::time::sleep(std::time::Duration::from_millis(50)).await;
    }
    let scene = Scene::new(
        "flyover",
        Settings {
            width: 256,
            height: 144,
            frames: 8,
            spp: 1,
            jitter: Jitter::Halton(8),
            noise: false,
            seed: 1,
            shading: 1,
        },
    )
    .unwrap();
    let shot: Vec<Frame> = (0..8).map(|i| scene.frame(i)).collect();
    let start = std::time::Instant::now();
    let until = start + std::time::Duration::from_secs(secs);
    // Eight clients, each streaming its own taa session as fast as replies come back.
    let mut sessions = Vec::new();
    let mut good = Vec::new();
    for k in 0..8u64 {
        let mut c = Client::connect(grpc_url.clone()).await.unwrap();
        let mut req = session_req("taa");
        req.width = 256;
        req.height = 144;
        let s = c.inner.create_session(req).await.unwrap().into_inner();
        sessions.push(s.id.clone());
        let shot = shot.clone();
        good.push(tokio::spawn(async move {
            let mut rtts = Vec::new();
            let mut i = 0u64;
            let frames = std::iter::from_fn(|| {
                (std::time::Instant::now() < until).then(|| {
                    let mut f = shot[(i % 8) as usize].clone();
                    f.meta.index = i;
                    i += 1;
                    f
                })
            });
            let r = c
                .stream(
                    &s,
                    frames,
                    SendOptions {
                        reference: false,
                        ..F32
                    },
                    |r| rtts.push(r.round_trip_ms),
                )
                .await;
            (k, r.err(), rtts)
        }));
    }
    // Give the streams a moment to claim their sessions before the misbehaving client
    // tries to feed them.
    tokio::time::sleep(std::time::Duration::from_millis(500)).await;
    let bad = tokio::spawn(misbehave(http_addr, grpc_url.clone(), sessions, until));
    let mut rss = Vec::new();
    while std::time::Instant::now() < until {
        rss.push((start.elapsed().as_secs_f64(), rss_mib(pid)));
        tokio::time::sleep(std::time::Duration::from_millis(500)).await;
    }
    let mut all = Vec::new();
    for g in good {
        let (k, err, rtts) = g.await.unwrap();
        assert!(err.is_none(), "client {k}: {err:?}");
        all.extend(rtts);
    }
    let bad_requests = bad.await.unwrap();
    let wall = start.elapsed().as_secs_f64();
    all.sort_by(f64::total_cmp);
    let pct = |p: f64| all[((all.len() - 1) as f64 * p).round() as usize];
    let peak = rss.iter().map(|r| r.1).fold(0.0, f64::max);
    let half: Vec<(f64, f64)> = rss.iter().copied().filter(|r| r.0 >= secs as f64 / 2.0).collect();
    let (first, last) = (half.first().unwrap().1, half.last().unwrap().1);
    let metrics = http(http_addr, "GET", "/metrics", b"", "text/plain").await.2;
    let metrics = String::from_utf8_lossy(&metrics);
    let errors: Vec<&str> = metrics
        .lines()
        .filter(|l| l.starts_with("afterimage_errors_total{"))
        .collect();
    eprintln!(
        "soak: {secs} s, 8 clients x taa 256x144 (gRPC, f32, lockstep) + 1 misbehaving ({bad_requests} bad requests): {} frames, {:.1} frames/s; round trip p50 {:.1} ms, p99 {:.1} ms; server RSS peak {peak:.1} MiB, over the last half {first:.1} -> {last:.1} MiB ({:+.1}%); server errors {errors:?}",
        all.len(),
        all.len() as f64 / wall,
        pct(0.5),
        pct(0.99),
        (last / first - 1.0) * 100.0
    );
    assert!(
        all.len() as u64 > 8 * secs,
        "fewer than one frame per second per client"
    );
    assert!(
        last <= first * 1.10 + 8.0,
        "RSS grew from {first:.1} to {last:.1} MiB over the last half"
    );
    let _ = child.kill();
    let _ = child.wait();
}

// ---------------------------------------------------------------------------------------
// Several replicas behind one address: nginx hashing on x-afterimage-route.

/// A replica: an `afterimage serve` process on its own ports.
struct Replica {
    name: String,
    child: std::process::Child,
    alive: bool,
    grpc: u16,
    http: u16,
}

impl Replica {
    fn kill(&mut self) {
        self.child.kill().unwrap();
        self.child.wait().unwrap();
        self.alive = false;
    }

    fn start(name: &str) -> Replica {
        let (grpc, http) = (free_port(), free_port());
        let child = common::bin()
            .arg("serve")
            .env("AFTERIMAGE_GRPC_ADDR", format!("127.0.0.1:{grpc}"))
            .env("AFTERIMAGE_HTTP_ADDR", format!("127.0.0.1:{http}"))
            .env("AFTERIMAGE_REPLICA", name)
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .spawn()
            .unwrap();
        Replica {
            name: name.into(),
            child,
            alive: true,
            grpc,
            http,
        }
    }

    fn http_addr(&self) -> std::net::SocketAddr {
        std::net::SocketAddr::from(([127, 0, 0, 1], self.http))
    }
}

impl Drop for Replica {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Waits until `GET path` on `addr` answers 200.
async fn until_ready(addr: std::net::SocketAddr, path: &str) {
    for _ in 0..200 {
        if tokio::net::TcpStream::connect(addr).await.is_ok()
            && http(addr, "GET", path, b"", "text/plain").await.0 == 200
        {
            return;
        }
        tokio::time::sleep(std::time::Duration::from_millis(50)).await;
    }
    panic!("{addr}{path} never answered 200");
}

/// nginx in front of `replicas`: one gRPC (h2c) and one HTTP port, each upstream chosen by
/// `hash $http_x_afterimage_route consistent` as deploy/README.md says. None (with the
/// reason printed) when nginx is not installed, unless AFTERIMAGE_REQUIRE_NGINX is set.
fn start_nginx(dir: &std::path::Path, replicas: &[Replica]) -> Option<(std::process::Child, u16, u16)> {
    let nginx = ["nginx", "/usr/sbin/nginx"]
        .into_iter()
        .find(|n| std::process::Command::new(n).arg("-v").output().is_ok());
    let Some(nginx) = nginx else {
        common::skip_missing_tool(
            "AFTERIMAGE_REQUIRE_NGINX",
            "nginx is not installed",
            "nginx is not installed (Debian: nginx-light); the replica test did not run",
        );
        return None;
    };
    let (pg, ph) = (free_port(), free_port());
    let servers = |port: fn(&Replica) -> u16| -> String {
        replicas
            .iter()
            .map(|r| format!("    server 127.0.0.1:{};\n", port(r)))
            .collect()
    };
    let d = dir.display();
    let conf = format!(
        "worker_processes 1;\ndaemon off;\npid {d}/nginx.pid;\nerror_log {d}/error.log;\n\
         events {{ worker_connections 512; }}\n\
         http {{\n  access_log off;\n  client_body_temp_path {d}/body;\n  proxy_temp_path {d}/proxy;\n\
         fastcgi_temp_path {d}/fastcgi;\n  uwsgi_temp_path {d}/uwsgi;\n  scgi_temp_path {d}/scgi;\n\
         upstream grpc_replicas {{\n    hash $http_x_afterimage_route consistent;\n{}  }}\n\
         upstream http_replicas {{\n    hash $http_x_afterimage_route consistent;\n{}  }}\n\
         server {{ listen 127.0.0.1:{pg} http2; client_max_body_size 0;\n\
           location / {{ grpc_pass grpc://grpc_replicas; grpc_read_timeout 60s; grpc_send_timeout 60s; }} }}\n\
         server {{ listen 127.0.0.1:{ph}; client_max_body_size 64m;\n\
           location / {{ proxy_pass http://http_replicas; proxy_http_version 1.1; }} }}\n}}\n",
        servers(|r| r.grpc),
        servers(|r| r.http),
    );
    let path = dir.join("nginx.conf");
    std::fs::write(&path, conf).unwrap();
    let child = std::process::Command::new(nginx)
        .arg("-c")
        .arg(&path)
        .arg("-e")
        .arg(dir.join("error.log"))
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    Some((child, pg, ph))
}

/// Which replica holds session `id` (asked directly, not through the proxy).
async fn holder(replicas: &[Replica], id: &str) -> Option<usize> {
    for (k, r) in replicas.iter().enumerate() {
        if r.alive
            && http(
                r.http_addr(),
                "GET",
                &format!("/v1/sessions/{id}"),
                b"",
                "text/plain",
            )
            .await
            .0 == 200
        {
            return Some(k);
        }
    }
    None
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn replicas_behind_a_consistent_hash_proxy_keep_sessions_apart() {
    let dir = tempfile::tempdir().unwrap();
    let mut replicas: Vec<Replica> = (0..3).map(|k| Replica::start(&format!("replica-{k}"))).collect();
    for r in &replicas {
        until_ready(r.http_addr(), "/readyz").await;
    }
    let Some((nginx, pg, ph)) = start_nginx(dir.path(), &replicas) else {
        return;
    };
    let _nginx = KillOnDrop(nginx);
    let proxy_http = std::net::SocketAddr::from(([127, 0, 0, 1], ph));
    until_ready(proxy_http, "/healthz").await;
    let fr = frames("fence", 4, 1);
    let want = in_process("taa", &fr);
    let exrs: Vec<Vec<u8>> = fr
        .iter()
        .map(|f| {
            write_exr_bytes(
                f,
                &WriteOptions {
                    precision: Precision::F32,
                    compression: Compression::Zip,
                },
            )
            .unwrap()
        })
        .collect();
    // 12 gRPC and 12 HTTP sessions, each with its own routing key.
    let mut grpc = Vec::new();
    for k in 0..12 {
        let opts = afterimage::server::client::ConnectOptions {
            route: Some(format!("grpc-{k}")),
            ..Default::default()
        };
        let mut c = Client::connect_with(format!("http://127.0.0.1:{pg}"), &opts)
            .await
            .unwrap();
        let s = open(&mut c, "taa").await;
        grpc.push((c, s, Vec::<Rgb>::new()));
    }
    let mut web = Vec::new();
    for k in 0..12 {
        let route = format!("x-afterimage-route: http-{k}\r\n");
        let (st, _, body) = http_with(
            proxy_http,
            "POST",
            "/v1/sessions",
            &format!("{route}Content-Type: application/json\r\n"),
            br#"{"filter":"taa","width":64,"height":36}"#,
        )
        .await;
        assert_eq!(st, 201, "{}", String::from_utf8_lossy(&body));
        let id = serde_json::from_slice::<Value>(&body).unwrap()["id"]
            .as_str()
            .unwrap()
            .to_string();
        web.push((route, id, Vec::<Rgb>::new()));
    }
    // The keys spread the sessions over the replicas.
    let mut on = [0usize; 3];
    let mut grpc_on = Vec::new();
    for (_, s, _) in &grpc {
        let k = holder(&replicas, &s.id).await.expect("a replica holds it");
        on[k] += 1;
        grpc_on.push(k);
    }
    let mut web_on = Vec::new();
    for (_, id, _) in &web {
        let k = holder(&replicas, id).await.expect("a replica holds it");
        on[k] += 1;
        web_on.push(k);
    }
    assert!(
        on.iter().filter(|&&n| n > 0).count() >= 2,
        "sessions per replica {on:?}"
    );
    // Two frames each, then the busiest replica is killed.
    let send_http = |route: String, id: String, exr: Vec<u8>| async move {
        http_with(
            proxy_http,
            "POST",
            &format!("/v1/sessions/{id}/frames"),
            &format!("{route}Content-Type: image/x-exr\r\n"),
            &exr,
        )
        .await
    };
    for (c, s, got) in grpc.iter_mut() {
        got.extend(stream_all(c, s, &fr[..2], F32).await.unwrap());
    }
    for (route, id, got) in web.iter_mut() {
        for exr in &exrs[..2] {
            let (st, _, body) = send_http(route.clone(), id.clone(), exr.clone()).await;
            assert_eq!(st, 200, "{}", String::from_utf8_lossy(&body));
            got.push(exr_color(&body));
        }
    }
    let dead = (0..3).max_by_key(|&k| on[k]).unwrap();
    replicas[dead].kill();
    let dead_name = replicas[dead].name.clone();
    // Sessions on the other replicas carry on, bit for bit; the dead replica's clients get
    // "no session ... on replica X" from the replica the proxy now picks (or UNAVAILABLE).
    let mut lost = 0;
    for ((c, s, got), &k) in grpc.iter_mut().zip(&grpc_on) {
        let r = stream_all(c, s, &fr[2..], F32).await;
        if k == dead {
            let e = r.unwrap_err();
            assert!(
                (e.code() == Code::NotFound
                    && e.message().contains("x-afterimage-route")
                    && !e.message().contains(&dead_name))
                    || e.code() == Code::Unavailable,
                "{e:?}"
            );
            lost += 1;
        } else {
            got.extend(r.unwrap());
            same(got, &want, &format!("grpc session {}", s.id));
        }
    }
    for ((route, id, got), &k) in web.iter_mut().zip(&web_on) {
        for exr in &exrs[2..] {
            let (st, _, body) = send_http(route.clone(), id.clone(), exr.clone()).await;
            if k == dead {
                let text = String::from_utf8_lossy(&body).to_string();
                let log = std::fs::read_to_string(dir.path().join("error.log")).unwrap_or_default();
                assert!(
                    st == 404 && text.contains("on replica replica-") && !text.contains(&dead_name),
                    "{st} {text}\nnginx: {log}"
                );
            } else {
                assert_eq!(st, 200, "{}", String::from_utf8_lossy(&body));
                got.push(exr_color(&body));
            }
        }
        if k == dead {
            lost += 1;
        } else {
            same(got, &want, &format!("http session {id}"));
        }
    }
    assert_eq!(lost, on[dead]);
    // `afterimage stream` through the proxy: its replica is killed mid-run; it creates its
    // session again on another and answers every frame.
    let url = format!("http://127.0.0.1:{pg}");
    let route = "stream-run";
    // Which replica the key reaches over gRPC (nginx hashes each upstream's own server
    // list, so the HTTP upstream may send the same key elsewhere).
    let opts = afterimage::server::client::ConnectOptions {
        route: Some(route.into()),
        ..Default::default()
    };
    let mut c = Client::connect_with(format!("http://127.0.0.1:{pg}"), &opts)
        .await
        .unwrap();
    let probe = open(&mut c, "taa").await.id;
    let target = holder(&replicas, &probe).await.unwrap();
    let metrics = replicas[target].http_addr();
    let taa_frames = || async move {
        let (_, _, m) = http(metrics, "GET", "/metrics", b"", "text/plain").await;
        String::from_utf8_lossy(&m)
            .lines()
            .filter(|l| l.starts_with("afterimage_frames_total{filter=\"taa\"}"))
            .filter_map(|l| l.split_whitespace().last()?.parse::<u64>().ok())
            .sum::<u64>()
    };
    let before = taa_frames().await;
    let run = tokio::task::spawn_blocking(move || {
        common::bin()
            .args([
                "stream", "--server", &url, "--route", route, "--filter", "taa", "--scene", "fence",
            ])
            .args(["--size", "320x180", "--frames", "80", "--spp", "1"])
            .output()
            .unwrap()
    });
    // Kill the stream's replica once it has filtered some of the stream's frames.
    for _ in 0..2000 {
        if taa_frames().await >= before + 10 {
            break;
        }
        tokio::time::sleep(std::time::Duration::from_millis(5)).await;
    }
    replicas[target].kill();
    let out = run.await.unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(
        stdout.contains("80 frames of 320x180")
            && stdout.contains("was lost before frame")
            && stdout.contains("recreated"),
        "{stdout}"
    );
}

/// A child process killed when the test ends, passing or not.
struct KillOnDrop(std::process::Child);

impl Drop for KillOnDrop {
    fn drop(&mut self) {
        // SIGTERM: nginx's master stops its workers too (SIGKILL would orphan them).
        let _ = std::process::Command::new("kill")
            .arg(self.0.id().to_string())
            .status();
        let _ = self.0.wait();
    }
}

/// A session exported over HTTP and imported into a new session continues bit for bit
/// (colour and frame index), on the same state file format batch checkpoints use; a state
/// file that is damaged, too large, of another filter or size, or of a windowed filter is
/// refused with the reason, and the session it was sent to goes on as before.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_exported_session_continues_in_another() {
    let r = server(|_| {}).await;
    let addr = r.http_addr;
    let create = |body: &'static str| async move {
        let (st, _, b) = http(addr, "POST", "/v1/sessions", body.as_bytes(), "application/json").await;
        assert_eq!(st, 201, "{}", String::from_utf8_lossy(&b));
        serde_json::from_slice::<Value>(&b).unwrap()["id"]
            .as_str()
            .unwrap()
            .to_string()
    };
    let phlm = r#"{"filter":"phlm","width":64,"height":36}"#;
    let (a, b) = (create(phlm).await, create(phlm).await);
    let full = WriteOptions {
        precision: Precision::F32,
        compression: Compression::Zip,
    };
    let fr = frames("flyover", 6, 1);
    // Posts an EXR to a session; its reply's frame index and colour bits.
    let post = |id: String, exr: Vec<u8>| async move {
        let (st, _, body) = post_frame(addr, &id, &exr).await;
        assert_eq!(st, 200, "{}", String::from_utf8_lossy(&body));
        let f =
            afterimage::io::read_exr_frame_bytes(&body, std::path::Path::new("reply"), &Default::default())
                .unwrap();
        let bits: Vec<u32> = f
            .color()
            .iter()
            .flat_map(|p| p.data().iter().map(|v| v.to_bits()))
            .collect();
        (exr_record(&body)["index"].as_u64().unwrap(), bits)
    };
    for f in &fr[..3] {
        post(a.clone(), write_exr_bytes(f, &full).unwrap()).await;
    }
    let (st, head, state) = http(addr, "GET", &format!("/v1/sessions/{a}/state"), b"", "text/plain").await;
    assert_eq!(st, 200, "{}", String::from_utf8_lossy(&state));
    assert!(
        head.to_ascii_lowercase()
            .contains("application/vnd.afterimage.state"),
        "{head}"
    );
    let put = |id: String, body: Vec<u8>| async move {
        let (st, _, reply) = http(
            addr,
            "PUT",
            &format!("/v1/sessions/{id}/state"),
            &body,
            STATE_TYPE,
        )
        .await;
        (st, String::from_utf8_lossy(&reply).into_owned())
    };
    let (st, text) = put(b.clone(), state.clone()).await;
    assert_eq!(st, 200, "{text}");
    // Frames without an index: both number them on from the exported session's last.
    for f in &fr[3..] {
        let mut f = f.clone();
        f.meta.index = 0;
        let mut replies = Vec::new();
        for id in [&a, &b] {
            replies.push(post(id.clone(), plain_exr(&f)).await);
        }
        assert!(
            replies[0] == replies[1],
            "frame {}: the imported session differs",
            replies[0].0
        );
    }
    // Refusals, each naming what is wrong.
    let mut damaged = state.clone();
    let at = damaged.len() / 2;
    damaged[at] ^= 1;
    let taa = create(r#"{"filter":"taa","width":64,"height":36}"#).await;
    let small = create(r#"{"filter":"phlm","width":32,"height":18}"#).await;
    let window = create(r#"{"filter":"pixel_trace","width":64,"height":36}"#).await;
    for (id, body, want) in [
        (b.clone(), b"not a state".to_vec(), "not an afterimage state file"),
        (b.clone(), damaged, "checksum"),
        (taa.clone(), state.clone(), "does not fit filter taa"),
        (small.clone(), state.clone(), "pixels"),
        (window.clone(), state.clone(), "cannot save or load"),
    ] {
        let (st, text) = put(id, body).await;
        assert!(st == 400 || st == 413, "{want}: {st} {text}");
        assert!(text.contains(want), "{want}: {text}");
    }
    let (st, _, text) = http(
        addr,
        "GET",
        &format!("/v1/sessions/{window}/state"),
        b"",
        "text/plain",
    )
    .await;
    assert!(
        st == 400 && String::from_utf8_lossy(&text).contains("window"),
        "{st}"
    );
    // The session refused a state goes on from its own.
    let (index, _) = post(b.clone(), write_exr_bytes(&fr[5], &full).unwrap()).await;
    assert_eq!(index, fr[5].meta.index);
    r.shutdown().await.unwrap();
}

// Hardening, round 2: attacks that a client without any key, or a client that leaves, can
// make; each failed before its fix.

/// An HTTP/2 client that opens the connection (preface and settings), then only answers
/// the server's pings and settings until the server closes it; returns how long that took.
async fn ping_answerer(addr: std::net::SocketAddr) -> Option<std::time::Duration> {
    let t = std::time::Instant::now();
    let mut s = tokio::net::TcpStream::connect(addr).await.ok()?;
    s.write_all(b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n\0\0\0\x04\0\0\0\0\0")
        .await
        .ok()?;
    let mut head = [0u8; 9];
    loop {
        if s.read_exact(&mut head).await.is_err() {
            return Some(t.elapsed());
        }
        let len = u32::from_be_bytes([0, head[0], head[1], head[2]]) as usize;
        let mut payload = vec![0u8; len];
        if s.read_exact(&mut payload).await.is_err() {
            return Some(t.elapsed());
        }
        let (kind, flags) = (head[3], head[4]);
        let answer: Vec<u8> = match (kind, flags & 1) {
            // PING: the same payload back, flagged ACK.
            (6, 0) => [&[0, 0, 8, 6, 1, 0, 0, 0, 0][..], &payload].concat(),
            // SETTINGS: acknowledged.
            (4, 0) => vec![0, 0, 0, 4, 1, 0, 0, 0, 0],
            _ => continue,
        };
        if s.write_all(&answer).await.is_err() {
            return Some(t.elapsed());
        }
    }
}

/// `GET /healthz` from another client address (127.0.0.2), with its answer time.
async fn healthz_from_elsewhere(addr: std::net::SocketAddr) -> (u16, std::time::Duration) {
    let t = std::time::Instant::now();
    let sock = tokio::net::TcpSocket::new_v4().unwrap();
    sock.bind("127.0.0.2:0".parse().unwrap()).unwrap();
    let mut s = sock.connect(addr).await.expect("a slot for another client");
    s.write_all(b"GET /healthz HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n")
        .await
        .unwrap();
    let mut buf = Vec::new();
    let _ = s.read_to_end(&mut buf).await;
    let text = String::from_utf8_lossy(&buf);
    (
        text.get(9..12).and_then(|c| c.parse().ok()).unwrap_or(0),
        t.elapsed(),
    )
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn idle_http2_connections_that_answer_pings_lock_nobody_out() {
    let r = server(|c| {
        c.keepalive_interval_s = 1;
        c.header_timeout_s = 3;
    })
    .await;
    // 300 connections from one address that never make a request but answer every ping.
    let mut attackers = Vec::new();
    for _ in 0..300 {
        attackers.push(tokio::spawn(ping_answerer(r.http_addr)));
    }
    tokio::time::sleep(std::time::Duration::from_millis(1500)).await;
    // Another client is answered at once, on both ports.
    let (st, took) = healthz_from_elsewhere(r.http_addr).await;
    assert_eq!(st, 200);
    assert!(took < std::time::Duration::from_secs(1), "/healthz took {took:?}");
    let t = std::time::Instant::now();
    let channel = tonic::transport::Endpoint::from_shared(format!("http://{}", r.grpc_addr))
        .unwrap()
        .local_address(Some("127.0.0.2".parse().unwrap()))
        .connect()
        .await
        .expect("a gRPC connection from another client");
    let mut c = pb::afterimage_client::AfterimageClient::new(channel);
    let s = c.create_session(session_req("taa")).await.unwrap().into_inner();
    assert!(
        t.elapsed() < std::time::Duration::from_secs(1),
        "{:?}",
        t.elapsed()
    );
    c.close_session(pb::CloseSessionRequest { id: s.id })
        .await
        .unwrap();
    // The attackers' connections are closed for making no request, pings or not: most at
    // accept (over the per-client cap), the rest at the first-request deadline.
    let closed = tokio::time::timeout(std::time::Duration::from_secs(15), async {
        let mut longest = std::time::Duration::ZERO;
        for a in attackers {
            longest = longest.max(a.await.unwrap().unwrap_or_default());
        }
        longest
    })
    .await
    .expect("every ping-answering connection is closed");
    assert!(
        closed >= std::time::Duration::from_secs(3),
        "the admitted ones lived until the deadline: {closed:?}"
    );
    let m = r.service.metrics.render(r.service.sessions.totals());
    assert!(
        m.contains("afterimage_errors_total{reason=\"too_many_connections_per_client\"}"),
        "{m}"
    );
    still_serving(&r).await;
    r.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn unread_replies_stay_in_the_memory_budget() {
    // phlm at 640x360 holds 50 MB of state, and its export (25 MB) is more than loopback's
    // socket buffers take: a client that does not read it leaves most of it with us.
    let budget: u64 = 192 << 20;
    let r = server(|c| c.memory_budget_mib = budget >> 20).await;
    let (w, h) = (640, 360);
    let id = http_session(
        r.http_addr,
        &format!(r#"{{"filter":"phlm","width":{w},"height":{h}}}"#),
    )
    .await;
    let f = {
        let s = Settings {
            width: w,
            height: h,
            frames: 1,
            spp: 1,
            jitter: Jitter::None,
            noise: false,
            seed: 1,
            shading: 1,
        };
        Scene::new("fence", s).unwrap().frame(0)
    };
    let (st, _, _) = post_frame(r.http_addr, &id, &plain_exr(&f)).await;
    assert_eq!(st, 200);
    let used = || r.service.sessions.totals().budget_used;
    let idle = used();
    // Exports nobody reads: each holds its reply in the budget until it is read, so once
    // the budget is full the next is refused (429) instead of growing memory past it.
    let head = format!("GET /v1/sessions/{id}/state HTTP/1.1\r\nHost: x\r\n\r\n");
    let mut unread = Vec::new();
    let mut refused = 0;
    for _ in 0..24 {
        let mut s = tokio::net::TcpStream::connect(r.http_addr).await.unwrap();
        s.write_all(head.as_bytes()).await.unwrap();
        // Only the start of the answer: a 429 fits, a 200's state does not.
        let mut buf = vec![0u8; 512];
        let n = s.read(&mut buf).await.unwrap();
        let text = String::from_utf8_lossy(&buf[..n]).to_string();
        if text.starts_with("HTTP/1.1 429") {
            refused += 1;
        } else {
            assert!(text.starts_with("HTTP/1.1 200"), "{text}");
        }
        unread.push(s);
        assert!(used() <= budget, "budget over its limit: {}", used());
    }
    assert!((1..24).contains(&refused), "{refused} of 24 exports refused");
    assert!(
        used() > idle,
        "the unread replies are counted ({} vs {idle})",
        used()
    );
    drop(unread);
    let back = tokio::time::timeout(std::time::Duration::from_secs(5), async {
        while used() > idle {
            tokio::time::sleep(std::time::Duration::from_millis(20)).await;
        }
    })
    .await;
    assert!(
        back.is_ok(),
        "the replies' reservations came back: {} vs {idle}",
        used()
    );
    r.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn forged_state_is_refused_plane_by_plane_and_unsigned_state_with_a_key() {
    use afterimage::pipeline::state::{FilterState, StateKey};
    let secret = "replica-secret-0123";
    let r = server(|c| c.state_key = StateKey::new(secret.as_bytes())).await;
    let addr = r.http_addr;
    let id = http_session(addr, r#"{"filter":"phlm","width":64,"height":36}"#).await;
    for f in &frames("flyover", 2, 1) {
        let (st, _, _) = post_frame(addr, &id, &plain_exr(f)).await;
        assert_eq!(st, 200);
    }
    let (st, _, state) = http(
        addr,
        "GET",
        &format!("/v1/sessions/{id}/state"),
        b"",
        "text/plain",
    )
    .await;
    assert_eq!(st, 200);
    let path = format!("/v1/sessions/{id}/state");
    let put = |body: Vec<u8>| {
        let path = path.clone();
        async move {
            let (st, _, reply) = http(addr, "PUT", &path, &body, STATE_TYPE).await;
            (st, String::from_utf8_lossy(&reply).into_owned())
        }
    };
    // Its own export goes back in.
    let (st, text) = put(state.clone()).await;
    assert_eq!(st, 200, "{text}");
    let key = StateKey::new(secret.as_bytes()).unwrap();
    let st0 = FilterState::decode_with(&state, 64 * 36, Some(&key)).unwrap();
    // A history with a NaN, or a negative colour, signed with the server's own key (a
    // stolen key, or a bug): refused plane by plane, naming what and where.
    // phlm's state is one texel of STATE_PLANES floats a pixel; planes 22..25 are z.
    let texel = afterimage::filters::phlm::STATE_PLANES;
    let mut nan = st0.clone();
    nan.planes[0].data_mut()[texel * 5 + 23] = f32::NAN;
    let (st, text) = put(nan.encode_with(Some(&key))).await;
    assert_eq!(st, 400, "{text}");
    assert!(
        text.contains("plane 0") && text.contains("pixel (5, 0)") && text.contains("NaN"),
        "{text}"
    );
    let mut negative = st0.clone();
    negative.planes[0].data_mut()[texel * 70 + 22] = -1.0;
    let (st, text) = put(negative.encode_with(Some(&key))).await;
    assert_eq!(st, 400, "{text}");
    assert!(
        text.contains("pixel (6, 1)") && text.contains("z") && text.contains("-1"),
        "{text}"
    );
    // A well-formed state with a recomputed SHA-256, as anyone can write: not signed.
    let (st, text) = put(st0.encode()).await;
    assert_eq!(st, 400, "{text}");
    assert!(text.contains("not signed"), "{text}");
    // The session goes on from its own state.
    let (st, _, _) = post_frame(addr, &id, &plain_exr(&frames("flyover", 3, 1)[2])).await;
    assert_eq!(st, 200);
    r.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_frame_trickled_a_byte_at_a_time_meets_its_whole_frame_deadline() {
    let r = server(|c| c.request_timeout_s = 2).await;
    let mut c = client(&r).await;
    let s = open(&mut c, "taa").await;
    let f = &frames("fence", 1, 3)[0];
    let parts = frame_parts(f, &s.id, &[afterimage::frame::ChannelKind::Color]);
    let frame_chunk::Part::Data(first) = &parts[1] else {
        panic!("a data chunk after the header")
    };
    // The header, then one byte every 0.5 s: each chunk well within the timeout.
    let (tx, rx) = tokio::sync::mpsc::channel(4);
    tx.send(pb::FrameChunk {
        part: Some(parts[0].clone()),
    })
    .await
    .unwrap();
    let data = first.data.clone();
    let trickle = tokio::spawn(async move {
        for k in 0..40 {
            let d = pb::DataChunk {
                data: data[k..k + 1].to_vec().into(),
            };
            if tx
                .send(pb::FrameChunk {
                    part: Some(frame_chunk::Part::Data(d)),
                })
                .await
                .is_err()
            {
                return;
            }
            tokio::time::sleep(std::time::Duration::from_millis(500)).await;
        }
    });
    let t = std::time::Instant::now();
    let mut replies = c
        .inner
        .stream(tokio_stream::wrappers::ReceiverStream::new(rx))
        .await
        .unwrap()
        .into_inner();
    let e = loop {
        match replies.message().await {
            Err(s) => break s,
            Ok(Some(_)) => continue,
            Ok(None) => panic!("the stream ended without an error"),
        }
    };
    let took = t.elapsed();
    trickle.abort();
    assert_eq!(e.code(), Code::InvalidArgument, "{e:?}");
    assert!(
        e.message()
            .contains("still missing after the request timeout of 2 s"),
        "{e:?}"
    );
    assert!(took < std::time::Duration::from_secs(4), "{took:?}");
    still_serving(&r).await;
    r.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_cancelled_window_stream_drops_its_window() {
    let r = server(|_| {}).await;
    let mut c = client(&r).await;
    let mut req = session_req("pixel_trace");
    req.params.insert("window".into(), "8".into());
    let s = c.inner.create_session(req).await.unwrap().into_inner();
    assert_eq!(s.lookahead, 4);
    // Three frames into the window, then the client goes away without ending its side.
    let fr = frames("fence", 3, 5);
    let (tx, rx) = tokio::sync::mpsc::channel(64);
    for f in &fr {
        for p in frame_parts(
            f,
            &s.id,
            &[
                afterimage::frame::ChannelKind::Color,
                afterimage::frame::ChannelKind::Motion,
            ],
        ) {
            tx.send(pb::FrameChunk { part: Some(p) }).await.unwrap();
        }
    }
    let call = c
        .inner
        .stream(tokio_stream::wrappers::ReceiverStream::new(rx))
        .await
        .unwrap();
    // Let the server take the frames in, then cancel the call.
    let frames_in = tokio::time::timeout(std::time::Duration::from_secs(10), async {
        loop {
            let info = r
                .service
                .sessions
                .get(&afterimage::session::Caller::ANONYMOUS, &s.id)
                .unwrap();
            if info.frames == 3 {
                break;
            }
            tokio::time::sleep(std::time::Duration::from_millis(20)).await;
        }
    })
    .await;
    assert!(frames_in.is_ok(), "the server filtered the three frames");
    drop(call);
    drop(tx);
    // Nobody will take the window's outputs: a flush on a new stream finds none (before,
    // the three frames waited in the session for whoever flushed it next).
    tokio::time::sleep(std::time::Duration::from_millis(300)).await;
    let flushed = flush_all(r.http_addr, &s.id).await;
    assert!(
        flushed.is_empty(),
        "{} outputs of a cancelled stream",
        flushed.len()
    );
    let m = r.service.metrics.render(r.service.sessions.totals());
    assert!(m.contains("afterimage_errors_total{reason=\"cancelled\"}"), "{m}");
    r.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_key_without_quotas_gets_a_share_not_the_whole_server() {
    let (r, _dir) = keyed_server(|c| c.max_sessions = 4).await;
    let mut b = keyed_client(&r, Some(KEY_B)).await;
    // Key b sets no quota: half the server's 4 sessions.
    for _ in 0..2 {
        open(&mut b, "taa").await;
    }
    let e = b.inner.create_session(session_req("taa")).await.unwrap_err();
    assert_eq!(e.code(), Code::ResourceExhausted, "{e:?}");
    assert!(
        e.message().contains("key b has 2 sessions open, its quota is 2"),
        "{e:?}"
    );
    // The other key still gets its sessions.
    let mut a = keyed_client(&r, Some(KEY_A)).await;
    open(&mut a, "taa").await;
    r.shutdown().await.unwrap();
}

/// Round trips of one 64x36 taa frame at a time on a fresh session, milliseconds.
async fn victim_round_trips(r: &Running, n: usize) -> Vec<f64> {
    let mut c = client(r).await;
    let s = open(&mut c, "taa").await;
    let fr = frames("fence", 1, 9);
    let mut ms = Vec::with_capacity(n);
    for _ in 0..n {
        let t = std::time::Instant::now();
        stream_all(&mut c, &s, &fr, F32).await.unwrap();
        ms.push(t.elapsed().as_secs_f64() * 1e3);
    }
    ms
}

fn p99(mut ms: Vec<f64>) -> f64 {
    ms.sort_by(f64::total_cmp);
    ms[((ms.len() as f64 * 0.99).ceil() as usize).clamp(1, ms.len()) - 1]
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
#[ignore = "a load run: cargo test --release --test server cancelled_window_streams -- --ignored --nocapture"]
async fn cancelled_window_streams_leave_other_clients_their_latency() {
    // Two pixel_trace streams at 512x512 with a window of WINDOW frames send half a window
    // (no output yet), end their side (the server then flushes every frame of it, each
    // traced through the window) and are cancelled at once; then a small client's round
    // trips are measured against its unloaded figure.
    let window: u32 = std::env::var("AFTERIMAGE_WINDOW")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(64);
    let r = server(|c| c.memory_budget_mib = 16 << 10).await;
    let quiet = p99(victim_round_trips(&r, 100).await);
    let big = {
        let s = Settings {
            width: 512,
            height: 512,
            frames: window as u64 / 2,
            spp: 1,
            jitter: Jitter::None,
            noise: false,
            seed: 2,
            shading: 1,
        };
        let sc = Scene::new("fence", s).unwrap();
        (0..window as u64 / 2).map(|i| sc.frame(i)).collect::<Vec<_>>()
    };
    let mut attackers = Vec::new();
    for _ in 0..2 {
        let mut c = client(&r).await;
        let mut req = session_req("pixel_trace");
        (req.width, req.height) = (512, 512);
        req.params.insert("window".into(), window.to_string());
        let s = c.inner.create_session(req).await.unwrap().into_inner();
        let big = big.clone();
        attackers.push(tokio::spawn(async move {
            let (tx, rx) = tokio::sync::mpsc::channel(8);
            let call = c
                .inner
                .stream(tokio_stream::wrappers::ReceiverStream::new(rx))
                .await
                .unwrap();
            for f in &big {
                for p in frame_parts(
                    f,
                    &s.id,
                    &[
                        afterimage::frame::ChannelKind::Color,
                        afterimage::frame::ChannelKind::Motion,
                    ],
                ) {
                    tx.send(pb::FrameChunk { part: Some(p) }).await.unwrap();
                }
            }
            // The end of the sequence (the server starts the flush), and gone.
            drop(tx);
            tokio::time::sleep(std::time::Duration::from_millis(50)).await;
            drop(call);
        }));
    }
    for a in attackers {
        a.await.unwrap();
    }
    let t = std::time::Instant::now();
    let loaded = p99(victim_round_trips(&r, 100).await);
    eprintln!(
        "victim p99: {quiet:.2} ms unloaded, {loaded:.2} ms after two cancelled {window}-frame window streams at 512x512 (measured over {:.1} s)",
        t.elapsed().as_secs_f64()
    );
    assert!(
        loaded < 2.0 * quiet.max(1.0),
        "p99 {loaded:.2} ms against {quiet:.2} ms unloaded"
    );
    r.shutdown().await.unwrap();
}

/// A memory budget with room for a session and one frame in flight but not two: a
/// pipelined stream (the next frame sent while the last is filtered) is still served, the
/// second frame waiting for the first's memory, with the colour of in-process filtering.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_budget_for_one_frame_in_flight_serves_a_pipelined_stream() {
    use afterimage::server::wire::{encode_frame, FramePlan};
    use afterimage::session::FrameShape;
    let (w, h) = (320u32, 180u32);
    let fr: Vec<Frame> = (0..4)
        .map(|i| afterimage::scene::synthetic_frame(w as usize, h as usize, i))
        .collect();
    // What the server reserves: the session's state, and per frame its wire bytes, the
    // decoded frame and two outputs.
    let info = afterimage::filters::info("taa").unwrap();
    let channels = afterimage::frame::ChannelSet::of(&info.uses).with(afterimage::frame::ChannelKind::Color);
    let shape = FrameShape {
        width: w,
        height: h,
        channels,
    };
    let (header, _) = encode_frame(
        &fr[0],
        "s",
        channels,
        pb::SampleType::F32,
        pb::Compression::None,
        1 << 20,
    );
    let plan = FramePlan::check(&header, shape, u64::MAX).unwrap();
    let frame = plan.wire_bytes + plan.decoded_bytes + 2 * shape.output_bytes();
    let (_, state_bpp) = afterimage::filters::create_sized("taa", &Default::default()).unwrap();
    // The session's state and the planes of one decoded frame it keeps for the next.
    let state = state_bpp as u64 * shape.pixels() + shape.decoded_bytes();
    let budget_mib = (state + frame + frame / 2) >> 20;
    assert!(
        (budget_mib << 20) >= state + frame && (budget_mib << 20) < state + 2 * frame,
        "the budget holds one frame in flight, not two"
    );
    let r = server(|c| c.memory_budget_mib = budget_mib).await;
    let mut c = client(&r).await;
    let s = c
        .inner
        .create_session(pb::CreateSessionRequest {
            width: w,
            height: h,
            ..session_req("taa")
        })
        .await
        .unwrap()
        .into_inner();
    let opts = SendOptions {
        reference: false,
        in_flight: 2,
        ..F32
    };
    same(
        &stream_all(&mut c, &s, &fr, opts).await.unwrap(),
        &in_process("taa", &fr),
        "taa, a budget for one frame in flight",
    );
    r.shutdown().await.unwrap();
}

/// A renderer's own client: `afterimage-client` alone (named planes in, planes out, no
/// frame types of ours) streams a session and gets the colour of in-process filtering,
/// two frames in flight.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_client_crate_streams_named_planes() {
    use afterimage::frame::ChannelKind;
    use afterimage_client::frame::{encode, Channel, Encoding, FrameData};
    let r = server(|_| {}).await;
    let mut inner =
        afterimage_client::connect::connect(format!("http://{}", r.grpc_addr), &Default::default())
            .await
            .unwrap();
    let s = inner
        .create_session(session_req("taa"))
        .await
        .unwrap()
        .into_inner();
    let fr = frames("moving-sphere", 5, 1);
    let how = Encoding {
        sample: pb::SampleType::F32,
        compression: pb::Compression::None,
        max_chunk: s.max_chunk_bytes as usize,
    };
    let encoded: Vec<_> = fr
        .iter()
        .map(|f| {
            let kinds = [ChannelKind::Color, ChannelKind::Depth, ChannelKind::Motion];
            let planes: Vec<Vec<&[f32]>> = kinds
                .iter()
                .map(|&k| f.planes(k).unwrap().iter().map(|p| p.data()).collect())
                .collect();
            let data = FrameData {
                index: f.meta.index,
                reset: f.meta.reset,
                jitter: f.meta.jitter,
                channels: kinds
                    .iter()
                    .zip(&planes)
                    .map(|(k, p)| Channel {
                        name: k.name(),
                        planes: p,
                    })
                    .collect(),
                ..Default::default()
            };
            encode(&data, &s.id, how)
        })
        .collect();
    let mut got = Vec::new();
    afterimage_client::stream::stream(&mut inner, &s, encoded, 2, |reply| {
        assert_eq!((reply.width, reply.height), (64, 36));
        got.push(reply.color.map(|d| Plane::from_vec(64, 36, d).unwrap()));
    })
    .await
    .unwrap();
    same(&got, &in_process("taa", &fr), "afterimage-client, named planes");
    r.shutdown().await.unwrap();
}

async fn channel(r: &Running) -> tonic::transport::Channel {
    tonic::transport::Channel::from_shared(format!("http://{}", r.grpc_addr))
        .unwrap()
        .connect()
        .await
        .unwrap()
}

/// `grpc.health.v1.Health/Check` for `service`, without an API key.
async fn health_of(r: &Running, service: &str) -> Result<i32, tonic::Status> {
    use tonic_health::pb::{health_client::HealthClient, HealthCheckRequest};
    HealthClient::new(channel(r).await)
        .check(HealthCheckRequest {
            service: service.into(),
        })
        .await
        .map(|resp| resp.into_inner().status)
}

const SERVING: i32 = tonic_health::pb::health_check_response::ServingStatus::Serving as i32;
const NOT_SERVING: i32 = tonic_health::pb::health_check_response::ServingStatus::NotServing as i32;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn grpc_health_serves_without_a_key_and_turns_not_serving_on_drain() {
    use tokio_stream::StreamExt;
    use tonic_health::pb::{health_client::HealthClient, HealthCheckRequest};
    let (r, _dir) = keyed_server(|c| c.shutdown_deadline_s = 30).await;
    // The server has keys: the protocol refuses a call without one, health answers it.
    let mut c = keyed_client(&r, None).await;
    let e = c.inner.create_session(session_req("taa")).await.unwrap_err();
    assert_eq!(e.code(), Code::Unauthenticated, "{e:?}");
    for name in ["", "afterimage.v1.Afterimage"] {
        assert_eq!(health_of(&r, name).await.unwrap(), SERVING, "{name:?}");
    }
    let e = health_of(&r, "no.such.Service").await.unwrap_err();
    assert_eq!(e.code(), Code::NotFound, "{e:?}");
    // A watcher sees the drain.
    let mut watch = HealthClient::new(channel(&r).await)
        .watch(HealthCheckRequest {
            service: String::new(),
        })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(watch.next().await.unwrap().unwrap().status, SERVING);
    // Draining (what SIGTERM starts): /readyz turns 503 and health NOT_SERVING.
    r.service.drain();
    let next = tokio::time::timeout(std::time::Duration::from_secs(5), watch.next()).await;
    assert_eq!(next.unwrap().unwrap().unwrap().status, NOT_SERVING);
    assert_eq!(
        http(r.http_addr, "GET", "/readyz", b"", "text/plain").await.0,
        503
    );
    for name in ["", "afterimage.v1.Afterimage"] {
        assert_eq!(health_of(&r, name).await.unwrap(), NOT_SERVING, "{name:?}");
    }
    // The open Watch stream ends when the listeners close, so it does not hold the
    // shutdown up to its deadline (30 s here).
    let t = std::time::Instant::now();
    r.shutdown().await.unwrap();
    assert!(t.elapsed().as_secs() < 10, "shutdown took {:?}", t.elapsed());
    let end = tokio::time::timeout(std::time::Duration::from_secs(5), watch.next()).await;
    assert!(
        matches!(end, Ok(None | Some(Err(_)))),
        "the Watch stream ended: {end:?}"
    );
}

/// The services a reflection v1 `ListServices` names, and the descriptor of the file that
/// defines `symbol` (`FileContainingSymbol`), without an API key.
async fn reflect_v1(r: &Running, symbol: &str) -> Result<(Vec<String>, Vec<Vec<u8>>), tonic::Status> {
    use tonic_reflection::pb::v1::{
        server_reflection_client::ServerReflectionClient, server_reflection_request::MessageRequest,
        server_reflection_response::MessageResponse, ServerReflectionRequest,
    };
    let req = |m| ServerReflectionRequest {
        host: String::new(),
        message_request: Some(m),
    };
    let mut replies = ServerReflectionClient::new(channel(r).await)
        .server_reflection_info(tokio_stream::iter([
            req(MessageRequest::ListServices(String::new())),
            req(MessageRequest::FileContainingSymbol(symbol.into())),
        ]))
        .await?
        .into_inner();
    let mut names = Vec::new();
    let mut files = Vec::new();
    while let Some(reply) = replies.message().await? {
        match reply.message_response {
            Some(MessageResponse::ListServicesResponse(l)) => {
                names.extend(l.service.into_iter().map(|s| s.name))
            }
            Some(MessageResponse::FileDescriptorResponse(f)) => files = f.file_descriptor_proto,
            other => panic!("unexpected reply {other:?}"),
        }
    }
    Ok((names, files))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn grpc_reflection_lists_the_service_unless_turned_off() {
    let (r, _dir) = keyed_server(|_| {}).await;
    let (names, files) = reflect_v1(&r, "afterimage.v1.Afterimage").await.unwrap();
    for name in [
        "afterimage.v1.Afterimage",
        "grpc.health.v1.Health",
        "grpc.reflection.v1.ServerReflection",
    ] {
        assert!(names.iter().any(|n| n == name), "{name} not in {names:?}");
    }
    // The descriptor of afterimage.proto, with its methods (a tool builds calls from it).
    let file = files.concat();
    for part in [
        &b"afterimage/v1/afterimage.proto"[..],
        b"CreateSession",
        b"FrameChunk",
    ] {
        assert!(
            file.windows(part.len()).any(|w| w == part),
            "{} not in the descriptor",
            String::from_utf8_lossy(part)
        );
    }
    // v1alpha too (what older grpcurl and grpcui ask).
    {
        use tonic_reflection::pb::v1alpha::{
            server_reflection_client::ServerReflectionClient, server_reflection_request::MessageRequest,
            server_reflection_response::MessageResponse, ServerReflectionRequest,
        };
        let mut replies = ServerReflectionClient::new(channel(&r).await)
            .server_reflection_info(tokio_stream::iter([ServerReflectionRequest {
                host: String::new(),
                message_request: Some(MessageRequest::ListServices(String::new())),
            }]))
            .await
            .unwrap()
            .into_inner();
        match replies.message().await.unwrap().unwrap().message_response {
            Some(MessageResponse::ListServicesResponse(l)) => assert!(
                l.service.iter().any(|s| s.name == "afterimage.v1.Afterimage"),
                "{l:?}"
            ),
            other => panic!("unexpected reply {other:?}"),
        }
    }
    r.shutdown().await.unwrap();
    // Turned off: no reflection service at all, health still there.
    let (r, _dir) = keyed_server(|c| c.grpc_reflection = false).await;
    let e = reflect_v1(&r, "afterimage.v1.Afterimage").await.unwrap_err();
    assert_eq!(e.code(), Code::Unimplemented, "{e:?}");
    assert_eq!(health_of(&r, "").await.unwrap(), SERVING);
    r.shutdown().await.unwrap();
}

/// The shared memory regions this process holds open (the test's server runs in it):
/// its descriptors of memfds named `afterimage-region`.
fn regions_open() -> Vec<std::path::PathBuf> {
    std::fs::read_dir("/proc/self/fd")
        .unwrap()
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            std::fs::read_link(p).is_ok_and(|t| t.to_string_lossy().starts_with("/memfd:afterimage-region"))
        })
        .collect()
}

/// `--transport shm`: frames and replies go through the session's region, only headers
/// cross the socket, and the colour is the same bits as in process (f32) and as the
/// socket's f16 (f16); the region is the server user's alone and is gone with its
/// session.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn shared_memory_streams_match_the_socket_and_leave_nothing_behind() {
    use std::os::unix::fs::PermissionsExt;
    let r = server(|_| {}).await;
    let mut c = client(&r).await;
    let fr = frames("moving-sphere", 5, 2);
    let shm = SendOptions {
        reference: false,
        shared_memory: true,
        ..F32
    };
    // traa sends object ids (u32): f32 frames and ids are read in place from the region.
    for filter in ["taa", "phlm", "traa"] {
        for in_flight in [1, 2] {
            let s = open(&mut c, filter).await;
            let mut payload = 0;
            let mut got = Vec::new();
            c.stream(&s, fr.clone(), SendOptions { in_flight, ..shm }, |r| {
                payload += r.payload_bytes;
                got.push(r.color)
            })
            .await
            .unwrap();
            same(
                &got,
                &in_process(filter, &fr),
                &format!("{filter} shm, {in_flight} in flight"),
            );
            // The server's; the client let go of its own when its stream ended.
            let files = regions_open();
            assert_eq!(files.len(), 1, "one region for the session: {files:?}");
            let mode = std::fs::metadata(&files[0]).unwrap().permissions().mode();
            assert_eq!(mode & 0o777, 0o600, "{}", files[0].display());
            // The payload counts the frames' bytes (written in place), not the replies'.
            assert!(payload > 0);
            c.inner
                .close_session(pb::CloseSessionRequest { id: s.id })
                .await
                .unwrap();
            assert_eq!(
                regions_open(),
                Vec::<std::path::PathBuf>::new(),
                "gone with the session"
            );
        }
    }
    let s = open(&mut c, "taa").await;
    let f16 = SendOptions {
        sample: pb::SampleType::F16,
        ..shm
    };
    let through_shm = stream_all(&mut c, &s, &fr, f16).await.unwrap();
    let s = open(&mut c, "taa").await;
    let through_socket = stream_all(
        &mut c,
        &s,
        &fr,
        SendOptions {
            shared_memory: false,
            ..f16
        },
    )
    .await
    .unwrap();
    same(&through_shm, &through_socket, "f16: shm against the socket");
    r.shutdown().await.unwrap();
}

/// The shared memory path under attack: every bad offset, size or state gets a precise
/// status, the server never crashes, and the session still filters afterwards.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn shared_memory_refuses_bad_offsets_sizes_and_regions() {
    use afterimage::frame::ChannelKind::Color;
    let r = server(|_| {}).await;
    let mut c = client(&r).await;
    let fr = frames("flyover", 2, 1);
    let s = open(&mut c, "taa").await;
    let (w, h) = (64u64, 36u64);
    let frame_bytes = 3 * w * h * 4;
    let header = |at: Option<pb::SharedMemory>| {
        let mut p = frame_parts(&fr[0], &s.id, &[Color]);
        let frame_chunk::Part::Header(mut hd) = p.remove(0) else {
            unreachable!()
        };
        hd.shared_memory = at;
        (hd, p)
    };
    // A stream's frame may still be filtered when its client has its error (the data
    // chunk after an in-region header ends a stream whose frame is complete): the next
    // stream waits for the session rather than racing it.
    async fn send(c: &mut Client, parts: Vec<frame_chunk::Part>) -> tonic::Status {
        for _ in 0..100 {
            let st = raw_stream(c, parts.clone()).await;
            if !(st.code() == Code::FailedPrecondition && st.message().contains("busy")) {
                return st;
            }
            tokio::time::sleep(std::time::Duration::from_millis(20)).await;
        }
        panic!("session busy for 2 s");
    }
    let expect = |st: tonic::Status, code: Code, words: &[&str]| {
        assert_eq!(st.code(), code, "{}", st.message());
        for w in words {
            assert!(st.message().contains(w), "{:?} not in {:?}", w, st.message());
        }
    };
    let at = |offset, reply_offset| Some(pb::SharedMemory { offset, reply_offset });
    // No region yet.
    let (hd, _) = header(at(0, frame_bytes));
    expect(
        send(&mut c, vec![frame_chunk::Part::Header(hd)]).await,
        Code::InvalidArgument,
        &["no shared memory region", "OpenRegion"],
    );
    let open_region = |c: &mut Client, id: &str, bytes: u64| {
        let mut inner = c.inner.clone();
        let id = id.to_string();
        async move {
            inner
                .open_region(pb::OpenRegionRequest {
                    session_id: id,
                    bytes,
                })
                .await
                .map(|r| r.into_inner())
        }
    };
    // Sizes: zero, more than two frames and replies need, then a good one; the same size
    // again is the same region, another size is refused.
    // The session's channels and a reference, as f32, and an f32 reply, twice.
    let components: u64 = s
        .channels
        .iter()
        .map(|c| afterimage::frame::ChannelKind::from_name(c).unwrap().components() as u64)
        .sum::<u64>()
        + 3;
    let max = 2 * (w * h * components * 4 + w * h * 12);
    for bad in [0, max + 1, u64::MAX] {
        let e = open_region(&mut c, &s.id, bad).await.unwrap_err();
        expect(e, Code::InvalidArgument, &["expected 1 to", &max.to_string()]);
    }
    let bytes = 2 * frame_bytes + 2 * frame_bytes;
    let region = open_region(&mut c, &s.id, bytes).await.unwrap();
    assert_eq!(region.bytes, bytes);
    assert_eq!(open_region(&mut c, &s.id, bytes).await.unwrap().path, region.path);
    expect(
        open_region(&mut c, &s.id, bytes - 1).await.unwrap_err(),
        Code::InvalidArgument,
        &["has a region of", "one region"],
    );
    // Another session's id that is not ours, and a windowed filter's session.
    expect(
        open_region(&mut c, "0123456789abcdef0123456789abcdef", bytes)
            .await
            .unwrap_err(),
        Code::NotFound,
        &[],
    );
    let windowed = open(&mut c, "pixel_trace").await;
    expect(
        open_region(&mut c, &windowed.id, bytes).await.unwrap_err(),
        Code::InvalidArgument,
        &["windowed filter"],
    );
    // Offsets past the end, wrapping, overlapping the reply, a compressed reply, data
    // chunks after a header in the region.
    for (offset, reply, words) in [
        (bytes - 10, 0, &["the frame is", "past the end"][..]),
        (u64::MAX - 5, frame_bytes, &["past the end"]),
        (0, u64::MAX, &["the reply is", "past the end"]),
        (0, frame_bytes - 1, &["overlaps"]),
        (frame_bytes, 4, &["overlaps"]),
    ] {
        let (hd, _) = header(at(offset, reply));
        expect(
            send(&mut c, vec![frame_chunk::Part::Header(hd)]).await,
            Code::InvalidArgument,
            words,
        );
    }
    let (mut hd, _) = header(at(0, frame_bytes));
    hd.reply_compression = pb::Compression::Zstd as i32;
    expect(
        send(&mut c, vec![frame_chunk::Part::Header(hd)]).await,
        Code::InvalidArgument,
        &["uncompressed"],
    );
    let (hd, data) = header(at(0, frame_bytes));
    let mut parts = vec![frame_chunk::Part::Header(hd)];
    parts.extend(data);
    expect(
        send(&mut c, parts).await,
        Code::InvalidArgument,
        &["no DataChunk follows"],
    );
    // A client cannot truncate or grow the region under the server's mapping (that
    // would kill the server on its next access): the region is sealed at its size.
    let file = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .open(&region.path)
        .unwrap();
    for len in [0, 100, bytes - 1, bytes + 4096] {
        let e = file.set_len(len).unwrap_err();
        assert_eq!(
            e.kind(),
            std::io::ErrorKind::PermissionDenied,
            "set_len({len}): {e}"
        );
    }
    assert_eq!(file.metadata().unwrap().len(), bytes);
    // Bytes a client writes into its slot are checked as any frame's: all NaN is refused.
    std::os::unix::fs::FileExt::write_all_at(&file, &vec![0xff; frame_bytes as usize], 0).unwrap();
    let (hd, _) = header(at(0, frame_bytes));
    expect(
        send(&mut c, vec![frame_chunk::Part::Header(hd)]).await,
        Code::InvalidArgument,
        &["NaN or infinite", "100.0%"],
    );
    // A client that lets go of its region (closes its file) changes nothing for the server.
    drop(file);
    // The session still filters (over the socket) after all of that. The frame of the
    // attack whose data chunk came after a complete in-region frame may have been filtered
    // before the error (see `send`), so the check starts with a cut: no history survives.
    let socket = SendOptions {
        reference: false,
        ..F32
    };
    let mut cut = fr.clone();
    cut[0].meta.reset = true;
    same(
        &stream_all(&mut c, &s, &cut, socket).await.unwrap(),
        &in_process("taa", &cut),
        "after the attacks",
    );
    r.shutdown().await.unwrap();
}

/// Regions belong to their session's key, and a server can refuse them.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn shared_memory_is_per_key_and_can_be_turned_off() {
    let (r, _keys) = keyed_server(|_| {}).await;
    let mut a = keyed_client(&r, Some(KEY_A)).await;
    let mut b = keyed_client(&r, Some(KEY_B)).await;
    let s = open(&mut a, "taa").await;
    let req = || pb::OpenRegionRequest {
        session_id: s.id.clone(),
        bytes: 1 << 16,
    };
    let e = b.inner.open_region(req()).await.unwrap_err();
    assert_eq!(e.code(), Code::NotFound, "{}", e.message());
    let region = a.inner.open_region(req()).await.unwrap().into_inner();
    assert!(std::path::Path::new(&region.path).is_file());
    // The path names a descriptor of this process (the server runs in the test's), whose
    // number another test's file may take once it is closed: compare the files.
    let file = || {
        std::fs::metadata(&region.path).map(|m| {
            use std::os::unix::fs::MetadataExt;
            (m.dev(), m.ino())
        })
    };
    let before = file().unwrap();
    r.shutdown().await.unwrap();
    assert!(
        file().map_or(true, |f| f != before),
        "a stopped server leaves no region"
    );
    let r = server(|c| c.shared_memory = false).await;
    let mut c = client(&r).await;
    let s = open(&mut c, "taa").await;
    let e = c
        .inner
        .open_region(pb::OpenRegionRequest {
            session_id: s.id,
            bytes: 1 << 16,
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::InvalidArgument, "{}", e.message());
    assert!(e.message().contains("shared_memory = false"), "{}", e.message());
    r.shutdown().await.unwrap();
}

//! `afterimage stream`: the remote-renderer side. Opens a session on a running server,
//! streams a sequence or a rendered scene to it over gRPC, writes the filtered frames, and
//! reports round-trip time next to the in-process filter time.

use super::outln;
use super::read_args::{ReadArgs, WriteArgs};
use afterimage::filters::create;
use afterimage::frame::{ChannelKind, Frame, Plane};
use afterimage::io::{
    refuse_overwrite, write_filtered, FilteredFrame, InputImage, Keep, OutputNaming, OutputOptions, Sequence,
};
use afterimage::metrics::{process_cpu_ms, Timing};
use afterimage::pipeline::params::parse_assignments;
use afterimage::scene::{Jitter, Scene, Settings};
use afterimage::server::client::{Client, ConnectOptions, Reply, SendOptions};
use afterimage::server::proto as pb;
use afterimage::session::params_from_json;
use afterimage::session::random_hex;
use anyhow::Context;
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use std::path::PathBuf;
use std::time::Instant;

/// Arguments of `stream`.
#[derive(Args, Debug)]
pub struct StreamArgs {
    /// gRPC address of the server (`https://` for TLS, with --tls-ca).
    #[arg(long, default_value = "http://127.0.0.1:50051")]
    server: String,
    /// API key of a server that has keys (sent as `authorization: Bearer KEY`).
    #[arg(long, env = "AFTERIMAGE_API_KEY", hide_env_values = true)]
    api_key: Option<String>,
    /// PEM file of the CA (or self-signed certificate) that the server's TLS certificate
    /// must chain to.
    #[arg(long)]
    tls_ca: Option<PathBuf>,
    /// The name in the server's certificate, when it is not the address's host.
    #[arg(long)]
    tls_domain: Option<String>,
    /// Filter name (see `afterimage filters`).
    #[arg(long)]
    filter: String,
    /// Parameter override, key=value (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    set: Vec<String>,
    /// Where the server runs the filter: cpu, gpu or auto (default: the server's own
    /// default); gpu-f16 or auto-f16 upload the colour to the GPU as f16. The session's
    /// answer says which it took.
    #[arg(long, value_name = "cpu|gpu|auto|gpu-f16|auto-f16")]
    backend: Option<afterimage::backend::BackendChoice>,
    /// Frames to send: a directory, pattern, glob or file.
    #[arg(
        short = 'i',
        long,
        conflicts_with = "scene",
        required_unless_present = "scene"
    )]
    input: Option<String>,
    /// Or a catalogue scene rendered here.
    #[arg(long)]
    scene: Option<String>,
    /// Scene size, WxH.
    #[arg(long, default_value = "256x144", value_parser = super::scene::parse_size)]
    size: (usize, usize),
    /// Scene frames.
    #[arg(long, default_value_t = 32)]
    frames: u64,
    /// Scene reference samples per pixel (a square number).
    #[arg(long, default_value_t = 16)]
    spp: u32,
    /// Send half floats (the reply comes back in f16 too).
    #[arg(long)]
    f16: bool,
    /// zstd-compress every channel and the reply.
    #[arg(long)]
    zstd: bool,
    /// Send the frames' reference channel, so each reply carries PSNR and SSIM.
    #[arg(long)]
    reference: bool,
    /// Also run the filter in this process on the same frames and compare the times.
    #[arg(long)]
    compare: bool,
    /// Frames sent ahead of their replies: 1 sends each frame when the last reply is in
    /// (the round trip is then a latency); 2 sends the next while the server filters the
    /// last (the server receives one frame while it filters another), for throughput.
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u32).range(1..=8))]
    in_flight: u32,
    /// How frames travel: `grpc` (their bytes in the stream) or `shm` (a client on the
    /// server's machine: the bytes go through a shared memory region the server makes for
    /// the session, and only headers cross the socket; uncompressed, causal filters, at
    /// most 2 in flight).
    #[arg(long, default_value = "grpc", value_parser = ["grpc", "shm"])]
    transport: String,
    /// The routing key sent with every call (`x-afterimage-route`), so that a proxy in
    /// front of several replicas sends all of this run's calls to one (default: random).
    #[arg(long, value_name = "KEY")]
    route: Option<String>,
    /// Times a lost session (its replica drained or killed: NOT_FOUND, UNAVAILABLE) is
    /// created again, going on from the first frame without a reply.
    #[arg(long, default_value_t = 3)]
    retries: usize,
    /// Where to write the filtered frames, as `filter -o` does: a directory (each output
    /// keeps its input's file name; frame_NNNN.exr for a scene) or a pattern with `####`;
    /// none: not written.
    #[arg(short = 'o', long, value_name = "DIR|PATTERN")]
    output: Option<String>,
    #[command(flatten)]
    read: ReadArgs,
    #[command(flatten)]
    write: WriteArgs,
}

/// A session that was lost mid-stream and created again.
struct Recreated {
    session: String,
    /// Frames it had filtered: the history the new session starts without.
    history: u64,
    /// The first frame the new session gets.
    next: u64,
    why: String,
}

/// Whether a stream's error `s` means its session is gone (the replica holding it was
/// drained or killed, or a proxy now routes elsewhere), so a new session can take over:
/// NOT_FOUND says so; after any other error the session is looked up, and is gone when no
/// server has it or none answers (NOT_FOUND, UNAVAILABLE, or a broken connection:
/// UNKNOWN, INTERNAL, CANCELLED, DEADLINE_EXCEEDED). An answer that it still exists
/// (failed, say), or a refusal (a key, a permission), leaves the error standing.
async fn session_lost(client: &mut Client, id: &str, s: &tonic::Status) -> bool {
    use tonic::Code;
    if s.code() == Code::NotFound {
        return true;
    }
    let probe = client
        .inner
        .get_session(pb::GetSessionRequest { id: id.to_string() })
        .await;
    matches!(probe, Err(e) if matches!(
        e.code(),
        Code::NotFound | Code::Unavailable | Code::Unknown | Code::Internal | Code::Cancelled | Code::DeadlineExceeded
    ))
}

/// Where a frame that was sent came from: its file, and the decoded input its output
/// replaces (None for a scene frame).
struct Source {
    path: PathBuf,
    input: Option<InputImage>,
}

fn load(args: &StreamArgs, keep: Keep) -> anyhow::Result<Vec<(Frame, Source)>> {
    if let Some(name) = &args.scene {
        let s = Settings {
            width: args.size.0,
            height: args.size.1,
            frames: args.frames,
            spp: args.spp,
            jitter: Jitter::Halton(8),
            noise: false,
            seed: 1,
            shading: 1,
        };
        let scene = Scene::new(name, s)?;
        return Ok((0..args.frames)
            .map(|i| {
                let source = Source {
                    path: PathBuf::from(format!("frame_{i:04}.exr")),
                    input: None,
                };
                (scene.frame(i), source)
            })
            .collect());
    }
    let seq = Sequence::open(args.input.as_deref().expect("clap requires input or scene"))?;
    let opts = args.read.options()?;
    seq.inputs(&opts)
        .zip(&seq.entries)
        .map(|(r, e)| {
            let (frame, mut input) = r?;
            input.trim_to(keep);
            let source = Source {
                path: e.path.clone(),
                input: Some(input),
            };
            Ok((frame, source))
        })
        .collect()
}

pub fn run(args: StreamArgs) -> anyhow::Result<()> {
    let naming = args.output.as_deref().map(OutputNaming::parse).transpose()?;
    let write = args.write.options()?;
    // Without --output nothing of the inputs is written: keep none of it.
    let keep = if naming.is_some() { write.keep } else { Keep::None };
    let (frames, sources): (Vec<Frame>, Vec<Source>) = load(&args, keep)?.into_iter().unzip();
    if let (Some(naming), Some(_)) = (&naming, &args.input) {
        let outputs: Vec<PathBuf> = frames
            .iter()
            .zip(&sources)
            .map(|(f, s)| naming.path(&s.path, f.meta.index))
            .collect();
        let inputs: Vec<PathBuf> = sources.iter().map(|s| s.path.clone()).collect();
        refuse_overwrite(&outputs, &inputs)?;
    }
    anyhow::ensure!(!frames.is_empty(), "no frames to send");
    let values = parse_assignments(&args.set)?;
    let bar = ProgressBar::new(frames.len() as u64).with_style(
        ProgressStyle::with_template("{msg:>10} [{bar:30}] {pos}/{len} frames, {eta} left")?
            .progress_chars("=> "),
    );
    bar.set_message(args.filter.clone());
    // The in-process figure drifts with the machine's load over a run: measured before the
    // stream and after, the two bracket it.
    let before = if args.compare {
        Some(in_process(&args.filter, &values, &frames)?)
    } else {
        None
    };
    let wall = Instant::now();
    let Shot {
        replies,
        recreated,
        streaming_s,
        steady,
        client_cpu_ms,
    } = send_shot(&args, &values, &frames, &bar, naming.is_some())?;
    let wall_s = wall.elapsed().as_secs_f64();
    bar.finish_and_clear();
    if let Some(naming) = &naming {
        write_replies(naming, &write, &replies, &frames, &sources)?;
    }
    for r in &recreated {
        outln!(
            "session {} was lost before frame {} ({}): recreated, {} frames of filter history lost",
            r.session,
            r.next,
            r.why,
            r.history
        );
    }
    let rtt_ms = print_figures(&args, &frames[0], &replies, wall_s)?;
    let period_ms = streaming_s * 1e3 / replies.len().max(1) as f64;
    // Once streaming: what a long shot approaches (the median also leaves out the first
    // gaps' fresh memory, as the in-process median does). With one reply, only the whole
    // span exists.
    let rate_ms = steady.rate_ms().unwrap_or(period_ms);
    let median_ms = steady.median_ms().unwrap_or(period_ms);
    outln!(
        "through the server: {rate_ms:.2} ms per frame ({:.1} frames/s) with {} in flight, from the first reply to the last (median gap {median_ms:.2} ms); {period_ms:.2} ms from the first frame sent (the session's region and first allocations included)",
        1e3 / rate_ms,
        args.in_flight
    );
    if let Some(ms) = client_cpu_ms {
        outln!(
            "client CPU: {:.2} ms per frame (encoding, sending, reading and decoding replies)",
            ms / replies.len().max(1) as f64
        );
    }
    if let Some(before) = before {
        let after = in_process(&args.filter, &values, &frames)?;
        let local = before.pool(&after);
        let median = local.median_ms();
        // Like with like: medians of the same frames (every one after the first: the gaps
        // between replies start at the first reply), and means over them.
        outln!(
            "in process: median {median:.2} ms/frame over {} ({:.2} before the stream, {:.2} after; mean {:.2}); the round trip adds {:.2} ms ({:.2}x); through the server {:.2}x median to median, {:.2}x mean to mean ({:.2}x from the first frame sent)",
            if frames.len() > 1 {
                "both runs' frames after the first"
            } else {
                "both runs' one frame"
            },
            before.median_ms(),
            after.median_ms(),
            local.mean_ms(),
            rtt_ms - median,
            rtt_ms / median,
            median_ms / median,
            rate_ms / local.mean_ms(),
            period_ms / median
        );
        if let Some((cpu_ms, busy)) = local.cpu_per_frame() {
            outln!("in process: {cpu_ms:.2} ms of CPU per frame ({busy:.2} cores busy while filtering)");
        }
        if let Some(floor) = copy_floor_ms(&args.filter, &frames) {
            outln!(
                "copy floor: {floor:.2} ms/frame to copy the channels the filter uses once in and its colour once out on one thread; a server that copies both is at least {:.2}x",
                (median + floor) / median
            );
        }
    }
    Ok(())
}

/// What [`send_shot`] gives back.
struct Shot {
    /// The replies, in order.
    replies: Vec<Reply>,
    /// The sessions that were lost and created again.
    recreated: Vec<Recreated>,
    /// Seconds spent streaming (from each session's first frame sent to its last reply).
    streaming_s: f64,
    /// The replies' arrivals, for the rate once streaming.
    steady: Steady,
    /// This process's CPU ms meanwhile (read before the runtime's threads end, since only
    /// live threads are counted).
    client_cpu_ms: Option<f64>,
}

/// Sends `frames` through one session (a new one after each loss, up to `--retries`) and
/// returns the replies and figures; the replies' colour only when `keep_color`.
fn send_shot(
    args: &StreamArgs,
    values: &serde_json::Map<String, serde_json::Value>,
    frames: &[Frame],
    bar: &ProgressBar,
    keep_color: bool,
) -> anyhow::Result<Shot> {
    let cpu = process_cpu_ms();
    let (w, h) = (frames[0].width() as u32, frames[0].height() as u32);
    let params = params_from_json(values);
    let opts = SendOptions {
        sample: if args.f16 {
            pb::SampleType::F16
        } else {
            pb::SampleType::F32
        },
        compression: if args.zstd {
            pb::Compression::Zstd
        } else {
            pb::Compression::None
        },
        reference: args.reference,
        in_flight: args.in_flight as usize,
        shared_memory: args.transport == "shm",
    };
    let route = match &args.route {
        Some(r) => r.clone(),
        None => random_hex(8).map_err(|e| anyhow::anyhow!("no randomness for a routing key: {e}"))?,
    };
    let mut replies = Vec::new();
    let mut recreated: Vec<Recreated> = Vec::new();
    let mut streaming_s = 0.0;
    let mut steady = Steady::default();
    let rt = tokio::runtime::Builder::new_multi_thread().enable_all().build()?;
    rt.block_on(async {
        let connect = ConnectOptions {
            api_key: args.api_key.clone(),
            tls_ca: args
                .tls_ca
                .as_ref()
                .map(|p| std::fs::read(p).with_context(|| format!("--tls-ca {}", p.display())))
                .transpose()?,
            tls_domain: args.tls_domain.clone(),
            route: Some(route.clone()),
        };
        let mut client = Client::connect_with(args.server.clone(), &connect)
            .await
            .with_context(|| format!("connecting to {}", args.server))?;
        let status = |s: tonic::Status| anyhow::anyhow!("{:?}: {}", s.code(), s.message());
        loop {
            let session = client
                .inner
                .create_session(pb::CreateSessionRequest {
                    filter: args.filter.clone(),
                    params: params.clone().into_iter().collect(),
                    width: w,
                    height: h,
                    motion: "internal".into(),
                    channels: vec![],
                    backend: args.backend.map(|b| b.to_string()).unwrap_or_default(),
                })
                .await
                .map_err(status)?
                .into_inner();
            // Frames are answered in order: the first without a reply is where this
            // session starts.
            let start = replies.len();
            let t = Instant::now();
            let mut arrivals = Arrivals::default();
            let sent = client
                .stream(&session, &frames[start..], opts, |r| {
                    arrivals.arrived(Instant::now());
                    bar.inc(1);
                    replies.push(kept(r, keep_color));
                })
                .await;
            streaming_s += t.elapsed().as_secs_f64();
            steady.add(&arrivals);
            match sent {
                Ok(()) => {
                    client
                        .inner
                        .close_session(pb::CloseSessionRequest { id: session.id })
                        .await
                        .map_err(status)?;
                    break;
                }
                // Every frame was answered before the stream failed: nothing is left to send.
                Err(_) if replies.len() == frames.len() => break,
                Err(s) if recreated.len() < args.retries && session_lost(&mut client, &session.id, &s).await => {
                    let r = Recreated {
                        session: session.id,
                        history: (replies.len() - start) as u64,
                        next: frames[replies.len()].meta.index,
                        why: format!("{:?}: {}", s.code(), s.message()),
                    };
                    bar.suspend(|| {
                        tracing::warn!(
                            "session {} lost ({}); a new session goes on from frame {}: the filter's history of {} frames is lost",
                            r.session, r.why, r.next, r.history
                        )
                    });
                    recreated.push(r);
                }
                Err(s) => return Err(status(s)),
            }
        }
        anyhow::Ok(())
    })?;
    Ok(Shot {
        replies,
        recreated,
        streaming_s,
        steady,
        client_cpu_ms: cpu.zip(process_cpu_ms()).map(|(a, b)| b - a),
    })
}

/// `r` as the shot holds it: without its colour unless it is to be written, so that a long
/// shot holds no frames.
fn kept(mut r: Reply, keep_color: bool) -> Reply {
    if !keep_color {
        r.color = std::array::from_fn(|_| afterimage::frame::Plane::new(0, 0));
    }
    r
}

/// One session's replies: when the last came, and the gaps between them so far.
#[derive(Default)]
struct Arrivals {
    last: Option<Instant>,
    /// Milliseconds between consecutive replies.
    gaps: Vec<f64>,
}

impl Arrivals {
    fn arrived(&mut self, at: Instant) {
        if let Some(last) = self.last {
            self.gaps.push((at - last).as_secs_f64() * 1e3);
        }
        self.last = Some(at);
    }
}

/// The gaps between consecutive replies of each session: the rate once the pipeline is
/// full.
#[derive(Default, Debug, PartialEq)]
struct Steady {
    gaps: Vec<f64>,
}

impl Steady {
    fn add(&mut self, a: &Arrivals) {
        self.gaps.extend_from_slice(&a.gaps);
    }

    /// Mean milliseconds per frame from each session's first reply to its last, when any
    /// session had two replies (it counts the first frames' fresh memory, see
    /// [`send_shot`]).
    fn rate_ms(&self) -> Option<f64> {
        (!self.gaps.is_empty()).then(|| self.gaps.iter().sum::<f64>() / self.gaps.len() as f64)
    }

    /// The median gap: a frame's period once streaming, the figure that compares with the
    /// in-process median.
    fn median_ms(&self) -> Option<f64> {
        (!self.gaps.is_empty()).then(|| Timing::of(&self.gaps).median_ms)
    }
}

/// Writes each reply's colour into a copy of its input file (`--output`).
fn write_replies(
    naming: &OutputNaming,
    write: &OutputOptions,
    replies: &[Reply],
    frames: &[Frame],
    sources: &[Source],
) -> anyhow::Result<()> {
    for r in replies {
        let k = frames
            .iter()
            .position(|f| f.meta.index == r.index)
            .with_context(|| format!("the server answered frame {}, which was not sent", r.index))?;
        let path = naming.path(&sources[k].path, r.index);
        let frame = FilteredFrame {
            color: &r.color,
            meta: &frames[k].meta,
            record: Some(&r.report.record_json),
            input: sources[k].input.as_ref(),
        };
        write_filtered(&path, &frame, write).with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}

/// Prints the round trip, server and transport figures (and the PSNR against a sent
/// reference); returns the round trip's median, ms.
fn print_figures(args: &StreamArgs, first: &Frame, replies: &[Reply], wall_s: f64) -> anyhow::Result<f64> {
    let (w, h) = (first.width(), first.height());
    let rtt: Vec<f64> = replies.iter().map(|r| r.round_trip_ms).collect();
    let server: Vec<f64> = replies.iter().map(|r| r.report.server_ms).collect();
    let filter: Vec<f64> = replies.iter().map(|r| r.report.total_ms).collect();
    let bytes: u64 = replies.iter().map(|r| r.payload_bytes).sum();
    let rtt_total_s: f64 = rtt.iter().sum::<f64>() / 1e3;
    // Time on the wire and in the codecs: the round trip less the server's decode+filter.
    let transport: Vec<f64> = rtt.iter().zip(&server).map(|(r, s)| (r - s).max(1e-3)).collect();
    let transport_ms = Timing::of(&transport).median_ms;
    let per_frame_mb = bytes as f64 / 1e6 / replies.len().max(1) as f64;
    outln!(
        "{} frames of {w}x{h} ({}{}) through {}: round trip median {:.2} ms (p95 {:.2}), server filter+decode median {:.2} ms (the filter alone {:.2}); payload {:.1} MB, {:.0} MB/s over the round trips; transport (round trip less server time) median {transport_ms:.2} ms/frame for {per_frame_mb:.1} MB = {:.0} MB/s; wall {:.2} s",
        replies.len(),
        if args.f16 { "f16" } else { "f32" },
        if args.zstd { ", zstd" } else { "" },
        args.filter,
        Timing::of(&rtt).median_ms,
        Timing::of(&rtt).p95_ms,
        Timing::of(&server).median_ms,
        Timing::of(&filter).median_ms,
        bytes as f64 / 1e6,
        bytes as f64 / 1e6 / rtt_total_s,
        per_frame_mb / (transport_ms / 1e3),
        wall_s
    );
    let psnr: Vec<f64> = replies.iter().filter_map(|r| r.report.psnr).collect();
    if !psnr.is_empty() {
        outln!(
            "mean PSNR against the sent reference: {:.2} dB",
            psnr.iter().sum::<f64>() / psnr.len() as f64
        );
    }
    Ok(Timing::of(&rtt).median_ms)
}

/// `--compare`'s figures: the same filter over the same frames in this process.
struct InProcess {
    /// Ms of each frame after the first: the frames the gaps between replies cover (the
    /// first, with no history yet, is cheaper, and fresh memory is touched in it).
    ms: Vec<f64>,
    /// CPU ms over the whole run and the run's wall ms, where the CPU time can be read.
    cpu: Option<(f64, f64)>,
    /// Frames in the run.
    frames: usize,
}

/// `--compare`: runs the filter over `frames` in this process.
fn in_process(
    filter: &str,
    values: &serde_json::Map<String, serde_json::Value>,
    frames: &[Frame],
) -> anyhow::Result<InProcess> {
    let mut f = create(filter, values)?;
    let mut ms = Vec::new();
    let cpu = process_cpu_ms();
    for fr in frames {
        let t = Instant::now();
        let outs = f.push(fr)?;
        ms.push(t.elapsed().as_secs_f64() * 1e3);
        for out in outs {
            f.recycle(out.color);
        }
    }
    let cpu_ms = cpu.zip(process_cpu_ms()).map(|(a, b)| b - a);
    f.finish()?;
    let wall_ms: f64 = ms.iter().sum();
    // One frame: it is all there is to time.
    let after_first = if ms.len() > 1 { ms.split_off(1) } else { ms };
    Ok(InProcess {
        ms: after_first,
        cpu: cpu_ms.map(|c| (c, wall_ms)),
        frames: frames.len(),
    })
}

impl InProcess {
    /// The median ms a frame (nearest rank, as every median here: of an even count, the
    /// lower middle one, which makes the ratios to it a little higher, if anything).
    fn median_ms(&self) -> f64 {
        Timing::of(&self.ms).median_ms
    }

    /// The two runs' frames as one sample (the machine drifts over a run: the runs before
    /// and after the stream bracket it).
    fn pool(&self, other: &InProcess) -> InProcess {
        InProcess {
            ms: [&self.ms[..], &other.ms].concat(),
            cpu: self.cpu.zip(other.cpu).map(|((a, x), (b, y))| (a + b, x + y)),
            frames: self.frames + other.frames,
        }
    }

    /// The mean ms a frame after the first (the span the rate through the server covers).
    fn mean_ms(&self) -> f64 {
        self.ms.iter().sum::<f64>() / self.ms.len().max(1) as f64
    }

    /// Mean CPU ms a frame, and the cores it kept busy.
    fn cpu_per_frame(&self) -> Option<(f64, f64)> {
        self.cpu
            .map(|(cpu, wall)| (cpu / self.frames.max(1) as f64, cpu / wall))
    }
}

/// `--compare`'s copy floor, median ms a frame: the channels of `frames` that `filter`
/// uses copied once into planes, and the colour once out, on this thread, as the
/// shared-memory transport copies them (the colour in counted as it is copied,
/// [`afterimage_shm::copy_f32`]; the rest plain copies). gRPC's copies come on top of the
/// socket's.
fn copy_floor_ms(filter: &str, frames: &[Frame]) -> Option<f64> {
    let uses = afterimage::filters::info(filter)?.uses;
    let mut into: Vec<Vec<f32>> = Vec::new();
    let mut out: Vec<Vec<f32>> = Vec::new();
    let copy = |dst: &mut Vec<Vec<f32>>, planes: &mut dyn Iterator<Item = (bool, &Plane<f32>)>| {
        for (k, (counted, p)) in planes.enumerate() {
            if dst.len() <= k {
                dst.push(Vec::new());
            }
            dst[k].resize(p.data().len(), 0.0);
            if counted {
                afterimage_shm::copy_f32(p.data(), &mut dst[k]);
            } else {
                dst[k].copy_from_slice(p.data());
            }
        }
    };
    let ms: Vec<f64> = frames
        .iter()
        .map(|fr| {
            let t = Instant::now();
            let used = uses.iter().filter_map(|&k| Some((k, fr.planes(k)?)));
            copy(
                &mut into,
                &mut used.flat_map(|(k, planes)| planes.iter().map(move |p| (k == ChannelKind::Color, p))),
            );
            copy(&mut out, &mut fr.color().iter().map(|p| (false, p)));
            std::hint::black_box((&into, &out));
            t.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    Some(Timing::of(&ms).median_ms)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    /// The rate counts the gaps between a session's replies, not its start, and a
    /// session with one reply adds no gap.
    #[test]
    fn the_rate_once_streaming_is_the_mean_gap_between_replies() {
        let t0 = Instant::now();
        let ms = |n: u64| t0 + Duration::from_millis(n);
        let mut steady = Steady::default();
        let mut a = Arrivals::default();
        for at in [500, 530, 560, 620] {
            a.arrived(ms(at));
        }
        steady.add(&a);
        let mut lone = Arrivals::default();
        lone.arrived(ms(900));
        steady.add(&lone);
        steady.add(&Arrivals::default());
        assert_eq!(steady.gaps.len(), 3);
        let close = afterimage::tolerance::Tolerance::abs(1e-6);
        let rate = steady.rate_ms().unwrap();
        assert!(close.eq(rate, 40.0), "{rate}");
        // The one slow gap moves the mean, not the median.
        let median = steady.median_ms().unwrap();
        assert!(close.eq(median, 30.0), "{median}");
        assert_eq!(Steady::default().rate_ms(), None);
        assert_eq!(Steady::default().median_ms(), None);
    }

    #[test]
    fn a_reply_keeps_its_colour_only_when_it_is_written() {
        let reply = || Reply {
            index: 3,
            color: std::array::from_fn(|_| afterimage::frame::Plane::filled(4, 2, 0.5)),
            report: pb::FrameReport::default(),
            round_trip_ms: 12.0,
            payload_bytes: 99,
        };
        let held = kept(reply(), true);
        assert_eq!(held.color[2].size(), (4, 2));
        let dropped = kept(reply(), false);
        assert!(dropped.color.iter().all(|p| p.data().is_empty()));
        assert_eq!((dropped.index, dropped.payload_bytes), (3, 99));
    }

    /// The in-process figures time the frames the gaps between replies cover (each run's
    /// frames after the first) and pool the runs before and after the stream.
    #[test]
    fn the_in_process_figures_pool_both_runs_frames_after_the_first() {
        let frames: Vec<Frame> = (0..3)
            .map(|_| {
                Frame::new(std::array::from_fn(|_| {
                    afterimage::frame::Plane::filled(8, 4, 0.5)
                }))
                .unwrap()
            })
            .collect();
        let run = in_process("passthrough", &serde_json::Map::new(), &frames).unwrap();
        assert_eq!((run.ms.len(), run.frames), (2, 3));
        let lone = in_process("passthrough", &serde_json::Map::new(), &frames[..1]).unwrap();
        assert_eq!(lone.ms.len(), 1);
        let before = InProcess {
            ms: vec![20.0, 22.0, 40.0],
            cpu: Some((60.0, 100.0)),
            frames: 4,
        };
        let after = InProcess {
            ms: vec![21.0, 23.0, 24.0],
            cpu: None,
            frames: 4,
        };
        let both = before.pool(&after);
        let close = afterimage::tolerance::Tolerance::abs(1e-9);
        // The one slow frame moves the mean (25), not the median (22, nearest rank); each
        // run alone has its own.
        assert!(close.eq(both.median_ms(), 22.0), "{}", both.median_ms());
        assert!(close.eq(both.mean_ms(), 25.0), "{}", both.mean_ms());
        assert!(close.eq(before.median_ms(), 22.0));
        assert!(close.eq(after.median_ms(), 23.0));
        assert_eq!(both.cpu_per_frame(), None);
        let (cpu, busy) = before.cpu_per_frame().unwrap();
        assert!(close.eq(cpu, 15.0) && close.eq(busy, 0.6), "{cpu} {busy}");
    }
}

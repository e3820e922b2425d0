//! The store's tests: a database in a temporary directory, reopened as a daemon
//! restart would.

use serde_json::Value;

use super::journal::frames_awaiting_hdr;
use super::*;
use crate::plan::{Lane, ScanPlan, Step, AUTO_FIT, FIT_MODELS};

fn plan() -> ScanPlan {
    ScanPlan {
        sample: "gold".into(),
        theta_l: vec![-20.0],
        shutter_s: vec![0.1, 0.01],
        auto_bracket: false,
    }
}

fn temp_store(name: &str) -> (std::path::PathBuf, Store) {
    let dir = std::env::temp_dir().join(format!("gonio-store-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let store = Store::open(&dir.join("gonio.sqlite")).unwrap();
    (dir, store)
}

fn done(store: &mut Store, id: i64, step: &StepRecord, followers: &[Step]) {
    store.step_started(id, step.index).unwrap();
    store
        .step_done(id, step.index, &Value::Null, followers, &now_rfc3339())
        .unwrap();
}

/// A scan of [`plan`], running.
fn started_scan(store: &mut Store) -> i64 {
    let id = store
        .insert_scans(&[NewScan {
            plan: plan(),
            sweep_id: None,
            not_before: None,
        }])
        .unwrap()[0];
    store
        .transition(id, &[ScanState::Queued], ScanState::Running, None)
        .unwrap();
    id
}

fn next(store: &Store, id: i64, lane: Lane) -> Option<Step> {
    store.next_step(id, lane).unwrap().map(|s| s.step)
}

/// A write that finds the disk full deletes the journal's reserve file and runs
/// once more in the space it frees; with no reserve left, the full disk is the
/// error, told from others (as SQLite reports it: here at its page limit).
#[test]
fn a_full_disk_frees_the_journal_reserve_for_one_more_try() {
    let (dir, mut store) = temp_store("reserve");
    let reserve = dir.join(storage::JOURNAL_RESERVE_FILE);
    std::fs::write(&reserve, vec![0u8; 4096]).unwrap();
    let full = || {
        StoreError::Sql(rusqlite::Error::SqliteFailure(
            rusqlite::ffi::Error::new(rusqlite::ffi::SQLITE_FULL),
            None,
        ))
    };
    let mut tries = 0;
    let written = store.writing(|_| {
        tries += 1;
        if tries == 1 {
            Err(full())
        } else {
            Ok(tries)
        }
    });
    assert_eq!(written.unwrap(), 2);
    assert!(!reserve.exists());
    tries = 0;
    let failed = store.writing(|_| -> Result<(), StoreError> {
        tries += 1;
        Err(full())
    });
    assert!(failed.unwrap_err().is_disk_full());
    assert_eq!(tries, 1);
    // What SQLite says when the database cannot grow.
    let pages: i64 = store
        .conn
        .query_row("PRAGMA page_count", [], |r| r.get(0))
        .unwrap();
    store
        .conn
        .pragma_update(None, "max_page_count", pages)
        .unwrap();
    let detail = "x".repeat(4000);
    let err = (0..100)
        .find_map(|_| store.log(1, None, "test", &detail).err())
        .expect("the page limit is reached");
    assert!(err.is_disk_full(), "{err}");
    assert!(!StoreError::State("?".into()).is_disk_full());
    std::fs::remove_dir_all(dir).ok();
}

#[test]
fn lanes_take_their_own_steps_and_the_scan_is_done_when_both_are() {
    let (dir, mut store) = temp_store("lanes");
    let auto = ScanPlan {
        theta_l: vec![-20.0, -25.0],
        shutter_s: vec![],
        auto_bracket: true,
        ..plan()
    };
    let id = store
        .insert_scans(&[NewScan {
            plan: auto,
            sweep_id: None,
            not_before: None,
        }])
        .unwrap()[0];
    let scan = store.next_for_hardware(now_unix()).unwrap().unwrap();
    // Home, then per θL move, meter, samples, HDR; extract, three fits and the
    // fit that chooses the model.
    assert_eq!(
        (scan.id, scan.state, scan.done, scan.total),
        (id, ScanState::Queued, 0, 14)
    );
    assert!(store
        .transition(id, &[ScanState::Queued], ScanState::Running, None)
        .unwrap());
    assert_eq!(next(&store, id, Lane::Hardware), Some(Step::Home));
    assert_eq!(next(&store, id, Lane::Processing), None);
    let steps = store.steps(id).unwrap();
    done(&mut store, id, &steps[0], &[]);
    done(&mut store, id, &steps[1], &[]);
    // Metering plans two captures after itself: the step total grows, the planned
    // total does not, and the metering counts once its bracket is captured.
    let bracket = ScanPlan::captures(-20.0, &[0.1, 0.01]);
    done(&mut store, id, &steps[2], &bracket);
    let scan = store.scan(id).unwrap().unwrap();
    assert_eq!(
        (scan.done, scan.total, scan.steps_done, scan.steps_total),
        (2, 14, 3, 16)
    );
    assert_eq!(scan.current_step.as_deref(), Some(&*bracket[0].describe()));
    assert_eq!(next(&store, id, Lane::Processing), None);
    assert_eq!(store.unprocessed_brackets().unwrap(), 0);
    let steps = store.steps(id).unwrap();
    done(&mut store, id, &steps[3], &[]);
    done(&mut store, id, &steps[4], &[]);
    assert_eq!(store.scan(id).unwrap().unwrap().done, 3);
    // The bracket is captured: processing may start while the arm moves on.
    assert_eq!(store.unprocessed_brackets().unwrap(), 1);
    assert_eq!(
        next(&store, id, Lane::Processing),
        Some(Step::Samples { theta_l: -20.0 })
    );
    assert_eq!(
        next(&store, id, Lane::Hardware),
        Some(Step::Move { theta_l: -25.0 })
    );
    let (processing_scan, samples) = store.next_for_processing(&[]).unwrap().unwrap();
    assert_eq!(processing_scan, id);
    // With the samples step running in the background, the HDR step is next; it is
    // also the HDR step ready to start ahead of the samples.
    let (_, beside) = store
        .next_for_processing(&[(id, samples.index)])
        .unwrap()
        .unwrap();
    assert_eq!(beside.step, Step::Hdr { theta_l: -20.0 });
    let (_, ahead) = store.next_beside(&[]).unwrap().unwrap();
    assert_eq!(ahead.index, beside.index);
    store.step_started(id, samples.index).unwrap();
    drop(store);
    // Reopened after a crash: the processing step that was running runs again.
    let mut store = Store::open(&dir.join("gonio.sqlite")).unwrap();
    let (_, again) = store.next_for_processing(&[]).unwrap().unwrap();
    assert_eq!(
        (again.index, again.state),
        (samples.index, StepState::Started)
    );
    assert_eq!(store.next_for_hardware(now_unix()).unwrap().unwrap().id, id);
    // The hardware lane finishes first; the scan is done with the last processing
    // step, whichever lane ends last.
    while let Some(step) = store.next_step(id, Lane::Hardware).unwrap() {
        let followers = if matches!(step.step, Step::Meter { .. }) {
            ScanPlan::captures(-25.0, &[0.1])
        } else {
            Vec::new()
        };
        done(&mut store, id, &step, &followers);
    }
    assert!(store.next_for_hardware(now_unix()).unwrap().is_none());
    assert_eq!(store.unprocessed_brackets().unwrap(), 2);
    while let Some((_, step)) = store.next_for_processing(&[]).unwrap() {
        assert_eq!(store.scan(id).unwrap().unwrap().state, ScanState::Running);
        done(&mut store, id, &step, &[]);
    }
    let scan = store.scan(id).unwrap().unwrap();
    assert_eq!(
        (scan.state, scan.done, scan.total, scan.steps_done),
        (ScanState::Done, 14, 14, 17)
    );
    assert!(scan.finished.is_some() && scan.current_step.is_none());
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn frames_awaiting_hdr_are_the_captures_of_brackets_not_merged() {
    let record = |index: u32, step: Step, done: bool, path: Option<&str>| StepRecord {
        index,
        step,
        state: if done {
            StepState::Done
        } else {
            StepState::Pending
        },
        started: None,
        finished: None,
        result: path.map(|p| serde_json::json!({ "path": p })),
    };
    let capture = |theta_l: f64, index: usize| Step::Capture {
        theta_l,
        index,
        shutter_s: 0.1,
    };
    let steps = [
        record(
            0,
            capture(-20.0, 0),
            true,
            Some("theta_l_-20.0/exp_00.tiff"),
        ),
        record(1, Step::Hdr { theta_l: -20.0 }, true, None),
        record(
            2,
            capture(-25.0, 0),
            true,
            Some("theta_l_-25.0/exp_00.tiff"),
        ),
        record(3, capture(-25.0, 1), false, None),
        record(4, Step::Hdr { theta_l: -25.0 }, false, None),
    ];
    assert_eq!(
        frames_awaiting_hdr(&steps),
        vec!["theta_l_-25.0/exp_00.tiff".to_owned()]
    );
    // A merge under way has decoded its frames: none are awaited.
    let mut merging = steps.clone();
    merging[4].state = StepState::Started;
    assert!(frames_awaiting_hdr(&merging).is_empty());
}

#[test]
fn processing_goes_on_while_a_device_is_away_but_not_when_paused() {
    let (dir, mut store) = temp_store("processable");
    let id = started_scan(&mut store);
    for step in &store.steps(id).unwrap()[..4] {
        done(&mut store, id, step, &[]);
    }
    assert!(store.next_for_processing(&[]).unwrap().is_some());
    store
        .transition(id, &[ScanState::Running], ScanState::Interrupted, None)
        .unwrap();
    assert!(store.next_for_processing(&[]).unwrap().is_some());
    assert!(store.next_for_hardware(now_unix()).unwrap().is_none());
    store
        .transition(id, &[ScanState::Interrupted], ScanState::Paused, None)
        .unwrap();
    assert!(store.next_for_processing(&[]).unwrap().is_none());
    assert_eq!(store.unprocessed_brackets().unwrap(), 0);
    std::fs::remove_dir_all(dir).unwrap();
}

/// A daemon start as `gonio serve` makes it: open, count the start, count the
/// crashes (limit 3) of a previous daemon that died of a fault in lane `faulted`.
/// Returns the store, the boot and the scans failed.
fn restart(dir: &std::path::Path, faulted: Option<Lane>) -> (Store, i64, Vec<i64>) {
    let mut store = Store::open(&dir.join("gonio.sqlite")).unwrap();
    let boot = store.begin_boot().unwrap();
    let failed = store.count_crashes(3, faulted).unwrap();
    (store, boot, failed)
}

/// A running scan of two queued ones, and the index of its first step.
fn running_scan(store: &mut Store) -> (Vec<i64>, u32) {
    let new = || NewScan {
        plan: plan(),
        sweep_id: None,
        not_before: None,
    };
    let ids = store.insert_scans(&[new(), new()]).unwrap();
    assert!(store
        .transition(ids[0], &[ScanState::Queued], ScanState::Running, None)
        .unwrap());
    let first = store.steps(ids[0]).unwrap()[0].index;
    (ids, first)
}

#[test]
fn a_step_running_at_three_faults_of_its_lane_fails_its_scan_and_the_queue_goes_on() {
    let (dir, mut store) = temp_store("crashes");
    store.begin_boot().unwrap();
    let (ids, first) = running_scan(&mut store);
    for death in 1..=3 {
        // The step starts, then the daemon dies of a fault in the hardware lane:
        // the next start counts it.
        store.step_started(ids[0], first).unwrap();
        drop(store);
        let failed;
        (store, _, failed) = restart(&dir, Some(Lane::Hardware));
        let scan = store.scan(ids[0]).unwrap().unwrap();
        if death < 3 {
            assert!(failed.is_empty());
            assert_eq!(scan.state, ScanState::Running);
            assert_eq!(
                store.next_for_hardware(now_unix()).unwrap().unwrap().id,
                ids[0]
            );
        } else {
            assert_eq!(failed, vec![ids[0]]);
            assert_eq!(scan.state, ScanState::Failed);
            assert_eq!(
                scan.error.as_deref(),
                Some("step \"home the arm\" crashed the daemon 3 times")
            );
            assert_eq!(store.steps(ids[0]).unwrap()[0].state, StepState::Pending);
        }
    }
    // The queue goes on with the next scan; a further start counts nothing more.
    assert_eq!(
        store.next_for_hardware(now_unix()).unwrap().unwrap().id,
        ids[1]
    );
    drop(store);
    assert!(restart(&dir, Some(Lane::Hardware)).2.is_empty());
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn kills_faults_of_another_lane_and_deaths_a_step_did_not_run_at_are_not_its_crashes() {
    let (dir, mut store) = temp_store("kills");
    store.begin_boot().unwrap();
    let (ids, first) = running_scan(&mut store);
    // Killed (or a power cut) five times while the step ran: no fault recorded, no
    // crash.
    for _ in 0..5 {
        store.step_started(ids[0], first).unwrap();
        drop(store);
        let failed;
        (store, _, failed) = restart(&dir, None);
        assert!(failed.is_empty());
    }
    // Faults of the processing lane while this hardware step ran: not its.
    for _ in 0..3 {
        store.step_started(ids[0], first).unwrap();
        drop(store);
        let failed;
        (store, _, failed) = restart(&dir, Some(Lane::Processing));
        assert!(failed.is_empty());
    }
    // Two faults while it ran, each followed by a fault in a start that had not
    // run it again yet: two crashes, not four.
    for _ in 0..2 {
        store.step_started(ids[0], first).unwrap();
        for _ in 0..2 {
            drop(store);
            let failed;
            (store, _, failed) = restart(&dir, Some(Lane::Hardware));
            assert!(failed.is_empty());
        }
    }
    let scan = store.scan(ids[0]).unwrap().unwrap();
    assert_eq!(scan.state, ScanState::Running);
    // The third fault it runs at fails it.
    store.step_started(ids[0], first).unwrap();
    drop(store);
    let (store, _, failed) = restart(&dir, Some(Lane::Hardware));
    assert_eq!(failed, vec![ids[0]]);
    drop(store);
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn start_time_and_transitions_gate_the_queue() {
    let (dir, mut store) = temp_store("gate");
    let later = now_unix() + 3600;
    let (sweep, ids) = store
        .insert_sweep(&serde_json::json!({}), Some(later), vec![plan(), plan()])
        .unwrap();
    assert_eq!(store.scans_of_sweep(sweep).unwrap().len(), 2);
    assert!(store.next_for_hardware(now_unix()).unwrap().is_none());
    assert_eq!(store.next_for_hardware(later).unwrap().unwrap().id, ids[0]);
    assert!(!store
        .transition(ids[0], &[ScanState::Running], ScanState::Paused, None)
        .unwrap());
    assert!(store
        .transition(ids[0], &[ScanState::Queued], ScanState::Cancelled, None)
        .unwrap());
    assert_eq!(store.next_for_hardware(later).unwrap().unwrap().id, ids[1]);
    assert_eq!(store.begin_boot().unwrap(), 1);
    assert_eq!(store.begin_boot().unwrap(), 2);
    std::fs::remove_dir_all(dir).unwrap();
}

/// Beside the other processing steps the lane starts a captured bracket's HDR map and,
/// once `samples.csv` is gathered, the auto fit, ahead of the per-model fits before it;
/// one of each kind at a time.
#[test]
fn the_auto_fit_runs_beside_the_model_fits_once_the_samples_are_gathered() {
    let (dir, mut store) = temp_store("beside");
    let id = started_scan(&mut store);
    let steps = store.steps(id).unwrap();
    let record = |wanted: &Step| steps.iter().find(|s| s.step == *wanted).unwrap().clone();
    let index = |wanted: &Step| record(wanted).index;
    let auto = Step::Fit {
        model: AUTO_FIT.0.into(),
    };
    let (hdr, extract) = (index(&Step::Hdr { theta_l: -20.0 }), index(&Step::Extract));
    let beside = |store: &Store, running: &[(i64, u32)]| {
        store.next_beside(running).unwrap().map(|(_, s)| s.step)
    };
    // Nothing beside before the bracket is captured.
    assert_eq!(beside(&store, &[]), None);
    for step in steps.iter().filter(|s| s.step.lane() == Lane::Hardware) {
        done(&mut store, id, step, &[]);
    }
    assert_eq!(beside(&store, &[]), Some(Step::Hdr { theta_l: -20.0 }));
    // The auto fit needs the samples gathered; the map being made does not hold it.
    let running = [(id, hdr)];
    assert_eq!(beside(&store, &running), None);
    done(
        &mut store,
        id,
        &record(&Step::Samples { theta_l: -20.0 }),
        &[],
    );
    assert_eq!(beside(&store, &running), None);
    store.step_started(id, extract).unwrap();
    assert_eq!(beside(&store, &running), None);
    done(&mut store, id, &record(&Step::Extract), &[]);
    assert_eq!(beside(&store, &running), Some(auto.clone()));
    let running = [(id, hdr), (id, index(&auto))];
    assert_eq!(beside(&store, &running), None);
    // The per-model fits run meanwhile, in the foreground.
    let (_, first) = store.next_for_processing(&running).unwrap().unwrap();
    assert!(matches!(&first.step, Step::Fit { model } if model == FIT_MODELS[0].0));
    // Without the map made, the foreground would take the auto fit only after them.
    for (model, _) in FIT_MODELS {
        let (_, next) = store.next_for_processing(&[(id, hdr)]).unwrap().unwrap();
        assert!(matches!(&next.step, Step::Fit { model: m } if m == model));
        done(&mut store, id, &next, &[]);
    }
    let (_, last) = store.next_for_processing(&[(id, hdr)]).unwrap().unwrap();
    assert_eq!(last.step, auto);
    std::fs::remove_dir_all(dir).unwrap();
}

/// A step run in the background is recorded after it ended, with the time it ended.
#[test]
fn a_step_is_recorded_with_the_time_it_ended() {
    let (dir, mut store) = temp_store("ended");
    let id = started_scan(&mut store);
    let step = store.steps(id).unwrap()[0].clone();
    store.step_started(id, step.index).unwrap();
    let ended = "2026-01-01T00:00:00Z";
    store
        .step_done(id, step.index, &Value::Null, &[], ended)
        .unwrap();
    let recorded = &store.steps(id).unwrap()[0];
    assert_eq!(recorded.finished.as_deref(), Some(ended));
    assert_eq!(recorded.state, StepState::Done);
    let _ = std::fs::remove_dir_all(&dir);
}

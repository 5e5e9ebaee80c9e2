#pragma once
/// The runnable dynamic graph, and edits that change it between ticks (controller switching).
///
///   GraphBuilder b;  ... b.Add<E>(...), b.Connect(out, in) ...
///   std::unique_ptr<Graph> g = b.Build();              // validated once: types, shapes,
///   for (Tick t; running; ++t) g->Evaluate(t);          // dangling inputs, cycles
///
/// A GraphEdit is prepared and validated off the loop thread against the running graph, then
/// applied at a tick boundary by the loop with Graph::Apply (pointer swaps only). The replaced
/// topology goes back inside the edit, to be destroyed off the loop thread.

#include <cstdint>
#include <memory>
#include <string>
#include <string_view>
#include <unordered_map>
#include <utility>
#include <vector>

#include "marionette/graph/entity.h"

namespace marionette::graph {

class GraphEdit;

class Graph {
 public:
  Graph(const Graph&) = delete;
  Graph& operator=(const Graph&) = delete;
  ~Graph();

  /// Evaluates tick t: runs every poll hook (outside data in), every state update and update
  /// hook (each pulls what it needs, every output computed at most once), then commits the
  /// states. Allocates nothing, takes no lock.
  void Evaluate(const Tick& t);

  const std::vector<std::shared_ptr<Entity>>& entities() const;
  Entity* FindEntity(std::string_view name) const;
  /// The entity called `name`; throws GraphError listing the entities otherwise.
  Entity& entity(std::string_view name) const;
  /// "entity.signal" -> the signal, or nullptr.
  SignalBase* FindSignal(std::string_view full_name) const;
  /// "entity.signal" -> the signal; throws GraphError naming what was not found.
  SignalBase& signal(std::string_view full_name) const;
  int num_signals() const;

  /// Graphviz dot of the entities (records with their input and output ports) and plugs;
  /// fixed inputs show their value when small.
  std::string ToDot() const;

  /// Increases by one with every applied edit.
  int64_t version() const;

  /// Turns per-entity timing on or off (between ticks). When on, every tick charges each
  /// entity's self time (graph/profiling.h) and folds it into the entity's window histogram;
  /// an entity whose tick exceeds its budget counts an overrun. Entities added by later edits
  /// are profiled too.
  void SetProfiling(bool on);
  bool profiling() const;
  /// The entities that overran their budget in the last evaluated tick, written into `out`
  /// (cleared first; reserve it: no allocation below its capacity). Returns how many.
  int LastOverruns(std::vector<const Entity*>* out) const;

  /// Applies `edit` (prepared against this graph at its current version). Real-time safe:
  /// re-plugs and a topology swap, nothing allocated or freed. Returns false and changes nothing
  /// when the graph changed since the edit was prepared.
  bool Apply(GraphEdit* edit);

  struct Topology;

 private:
  friend class GraphBuilder;
  friend class GraphEdit;
  explicit Graph(std::unique_ptr<Topology> topology);
  std::unique_ptr<Topology> topology_;
};

/// Collects entities and plugs, then validates them into a Graph.
class GraphBuilder {
 public:
  GraphBuilder();
  ~GraphBuilder();

  /// Constructs an entity owned by the graph; returns it to plug and configure.
  template <typename E, typename... Args>
  E& Add(Args&&... args) {
    auto entity = std::make_shared<E>(std::forward<Args>(args)...);
    E& ref = *entity;
    AddShared(std::move(entity));
    return ref;
  }
  /// Adds an entity made elsewhere (Python bindings).
  Entity& AddShared(std::shared_ptr<Entity> entity);

  /// Plugs `to` to `from`: both must belong to added entities, `from` an output and `to` an
  /// input of the same type and shape; throws GraphError otherwise.
  void Connect(SignalBase& from, SignalBase& to);
  /// Same with "entity.signal" names.
  void Connect(std::string_view from, std::string_view to);

  Entity* FindEntity(std::string_view name) const;

  /// Validates everything (unique names, every input plugged or set, plugs inside the graph,
  /// no cycle) and returns the graph; throws GraphError with every problem found.
  std::unique_ptr<Graph> Build();

 private:
  SignalBase& Resolve(std::string_view full_name) const;
  std::vector<std::shared_ptr<Entity>> entities_;
};

/// A change to a running graph: entities added and removed, inputs (re-)plugged. Everything but
/// Graph::Apply happens off the loop thread; the running graph is not touched until Apply.
class GraphEdit {
 public:
  /// Starts from `graph`'s current entities and version.
  explicit GraphEdit(const Graph& graph);
  ~GraphEdit();

  template <typename E, typename... Args>
  E& Add(Args&&... args) {
    auto entity = std::make_shared<E>(std::forward<Args>(args)...);
    E& ref = *entity;
    AddShared(std::move(entity));
    return ref;
  }
  Entity& AddShared(std::shared_ptr<Entity> entity);
  /// Removes the entity called `name` (it stays alive until the edit is destroyed).
  void Remove(std::string_view name);
  /// Plugs `to` to `from`. An input of a running entity is only recorded here and re-plugged
  /// by Graph::Apply; an input of a new entity is plugged at once.
  void Connect(SignalBase& from, SignalBase& to);
  void Connect(std::string_view from, std::string_view to);
  Entity* FindEntity(std::string_view name) const;

  /// Validates the edited graph like GraphBuilder::Build and precomputes its topology; throws
  /// GraphError. Must be called before Graph::Apply.
  void Prepare();
  bool prepared() const { return prepared_topology_ != nullptr; }
  int64_t base_version() const { return base_version_; }

 private:
  friend class Graph;
  SignalBase& Resolve(std::string_view full_name) const;
  bool IsNew(const Entity& e) const;

  int64_t base_version_;
  bool base_profiling_;
  std::vector<std::shared_ptr<Entity>> entities_;
  std::vector<std::shared_ptr<Entity>> new_entities_;
  std::vector<std::pair<InputSignalBase*, SignalBase*>> replugs_;  // live input -> new source
  std::unique_ptr<Graph::Topology> prepared_topology_;
  std::unique_ptr<Graph::Topology> retired_topology_;  // set by Apply, freed with the edit
};

/// Evaluates `n` ticks starting at `*t` (advancing it); for scripts and tests.
void RunTicks(Graph& graph, Tick* t, int64_t n);

}  // namespace marionette::graph
